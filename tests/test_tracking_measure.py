"""``starforge measure``: bodies from recordings of known geometry (C3D written with ezc3d, CSV
exports), a public C3D file, and bad recordings (one line, exit 2)."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from starforge.cli import main
from starforge.tracking.bodies import load_bodies
from starforge.tracking.measure import find_clusters, measure_bodies
from starforge.tracking.recording import read_recording, simulate_recording, write_c3d

DATA = Path(__file__).parent / "data" / "recordings"
C3D = DATA / "Optotrak.c3d"


def _bodies(rng, n: int, k: int = 4) -> list[np.ndarray]:
    """n random bodies of k markers, every pair 20-120 mm apart."""
    out = []
    while len(out) < n:
        P = rng.uniform(-50, 50, (k, 3))
        d = np.linalg.norm(P[:, None] - P[None], axis=2)[np.triu_indices(k, 1)]
        if d.min() > 20:
            out.append(P)
    return out


def _dists(P) -> np.ndarray:
    P = np.asarray(P, dtype=float)
    return np.array([np.linalg.norm(P[i] - P[j]) for i, j in itertools.combinations(range(len(P)), 2)])


def _shape_error(measured, truth) -> float:
    """Largest marker distance after the best rigid fit (SVD, written out here), mm."""
    A = np.asarray(measured) - np.mean(measured, axis=0)
    B = np.asarray(truth) - np.mean(truth, axis=0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    return float(np.linalg.norm(A @ R - B, axis=1).max())


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    rng = np.random.default_rng(7)
    truth = _bodies(rng, 10)
    rec = simulate_recording(truth, 1500, 0.2, 0.05, rng)
    path = tmp_path_factory.mktemp("rec") / "ten.c3d"
    write_c3d(path, rec.labels, rec.points_mm, rec.rate_hz)
    return truth, rec, path


def test_ten_bodies_with_noise_and_gaps_are_found_within_0_05_mm(synthetic, tmp_path):
    truth, rec, path = synthetic
    assert 0.04 < np.isnan(rec.points_mm[..., 0]).mean() < 0.06
    assert main(["measure", str(path), "--out", str(tmp_path / "m"), "-q"]) == 0
    report = json.loads((tmp_path / "m" / "measure.json").read_text())
    got = {tuple(b["labels"]): np.array(b["points_mm"]) for b in report["bodies"]}
    assert set(got) == {tuple(f"B{i + 1}_M{j + 1}" for j in range(4)) for i in range(10)}
    for i, T in enumerate(truth):
        P = got[tuple(f"B{i + 1}_M{j + 1}" for j in range(4))]
        assert _shape_error(P, T) <= 0.05
        assert np.abs(_dists(P) - _dists(T)).max() <= 0.05
    for b in report["bodies"]:
        assert all(0.1 < s < 0.5 for s in b["scatter_mm"])  # about sqrt(3) x 0.2 mm, less the fit's share
        assert min(report["identification"]["rate"].values()) >= 0.99
    # family.json: the measured bodies, verified, named, in the marker order of the labels
    fam = load_bodies(tmp_path / "m" / "family.json")
    assert fam.kind == "family" and len(fam.bodies) == 10
    for b in fam.bodies:
        i = int(b.name.removeprefix("B")) - 1
        assert np.abs(_dists(b.points_mm) - _dists(truth[i])).max() <= 0.05


def test_named_bodies_and_the_csv_table(synthetic, tmp_path):
    truth, rec, path = synthetic
    spec = "tool=B3_M1,B3_M2,B3_M3,B3_M4"
    assert main(["measure", str(path), "--body", spec, "--out", str(tmp_path / "m"), "-q"]) == 0
    bs = load_bodies(tmp_path / "m" / "bodies.csv")
    assert bs.names == ["tool"]
    assert _shape_error(bs.bodies[0].points_mm, truth[2]) <= 0.05


def test_a_marker_on_a_moving_part_is_left_out_of_the_cluster():
    rng = np.random.default_rng(3)
    (B,) = _bodies(rng, 1, k=5)
    rec = simulate_recording([B], 400, 0.2, 0.0, rng)
    P = rec.points_mm.copy()
    P[:, 4] += np.sin(np.arange(len(P)) / 10.0)[:, None] * 5.0  # a marker on a joint, 5 mm swing
    rec2 = type(rec)(rec.labels, P, rec.rate_hz, rec.source)
    assert find_clusters(rec2) == [[0, 1, 2, 3]]


def _write_qtm_tsv(path, rec) -> None:
    F, M, _ = rec.points_mm.shape
    lines = [
        f"NO_OF_FRAMES\t{F}",
        f"NO_OF_MARKERS\t{M}",
        f"FREQUENCY\t{rec.rate_hz:g}",
        "MARKER_NAMES\t" + "\t".join(rec.labels),
        "Frame\tTime\t" + "\t".join(f"{x} {c}" for x in rec.labels for c in "XYZ"),
    ]
    for f in range(F):
        cells = ["" if not np.isfinite(v) else repr(float(v)) for v in rec.points_mm[f].ravel()]
        lines.append(f"{f + 1}\t{f / rec.rate_hz:.5f}\t" + "\t".join(cells))
    path.write_text("\n".join(lines) + "\n")


def _write_vicon_csv(path, rec) -> None:
    F, M, _ = rec.points_mm.shape
    rows = ["Trajectories", f"{rec.rate_hz:g}", ",," + ",".join(f"Subj:{x},," for x in rec.labels)]
    rows += [
        "Frame,Sub Frame," + ",".join("X,Y,Z" for _ in rec.labels),
        ",," + ",".join("mm,mm,mm" for _ in rec.labels),
    ]
    for f in range(F):
        rows.append(
            f"{f + 1},0,"
            + ",".join("" if not np.isfinite(v) else repr(float(v)) for v in rec.points_mm[f].ravel())
        )
    path.write_text("\n".join(rows) + "\n\nModel Outputs\n")


def _write_motive_csv(path, rec) -> None:
    F, M, _ = rec.points_mm.shape
    cols = [x for x in rec.labels for _ in range(3)]
    rows = [
        "Format Version,1.23,Take Name,t,Export Frame Rate,200,Length Units,Meters",
        "",
        "Type,," + ",".join("Marker" for _ in cols),
        "Name,," + ",".join(cols),
        "ID,," + ",".join("1" for _ in cols),
        ",," + ",".join("Position" for _ in cols),
        "Frame,Time (Seconds)," + ",".join("X,Y,Z" for _ in rec.labels),
    ]
    for f in range(F):
        vals = ["" if not np.isfinite(v) else repr(float(v) / 1000.0) for v in rec.points_mm[f].ravel()]
        rows.append(f"{f},{f / 200:.4f}," + ",".join(vals))
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.parametrize("writer", [_write_qtm_tsv, _write_vicon_csv, _write_motive_csv])
def test_csv_exports_read_the_same_trajectories(writer, tmp_path):
    rng = np.random.default_rng(11)
    rec = simulate_recording(_bodies(rng, 2), 60, 0.2, 0.05, rng)
    path = tmp_path / ("rec.tsv" if writer is _write_qtm_tsv else "rec.csv")
    writer(path, rec)
    got = read_recording(path)
    assert got.labels == rec.labels
    assert np.array_equal(np.isnan(got.points_mm), np.isnan(rec.points_mm))
    assert np.nanmax(np.abs(got.points_mm - rec.points_mm)) < 1e-9
    assert [b.labels for b in measure_bodies(got)] == [rec.labels[:4], rec.labels[4:]]


def test_a_public_c3d_gives_bodies_identified_in_99_percent_of_frames(tmp_path):
    assert main(["measure", str(C3D), "--out", str(tmp_path / "m"), "-q"]) == 0
    report = json.loads((tmp_path / "m" / "measure.json").read_text())
    rates = report["identification"]["rate"]
    shown = {b["name"]: b["frames"] for b in report["bodies"]}
    overall = sum(rates[k] * shown[k] for k in rates) / sum(shown.values())
    assert len(rates) >= 8 and overall >= 0.99
    rec = read_recording(C3D)
    index = {x: i for i, x in enumerate(rec.labels)}
    for b in report["bodies"]:  # every frame's distances agree with the measured shape
        X = rec.points_mm[:, [index[x] for x in b["labels"]]]
        full = np.isfinite(X).all(axis=(1, 2))
        ref = _dists(b["points_mm"])
        worst = max(np.abs(_dists(x) - ref).max() for x in X[full])
        assert worst < 2.0  # within a tracker's matching window in every whole frame
    # check and convert take what measure writes
    assert (
        main(
            [
                "check",
                str(tmp_path / "m" / "family.json"),
                "--frames",
                "200",
                "--out",
                str(tmp_path / "c"),
                "-q",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "convert",
                str(tmp_path / "m" / "bodies.csv"),
                "--format",
                "qtm",
                "--out",
                str(tmp_path / "q"),
                "-q",
            ]
        )
        == 0
    )


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("cut.c3d", lambda: C3D.read_bytes()[:3000], "C3D"),
        ("junk.csv", lambda: b"a,b,c\n1,2,3\n", "not a recording"),
        (
            "nan.tsv",
            lambda: b"NO_OF_FRAMES\t1\nMARKER_NAMES\ta\tb\tc\n1\t0\tx\t1\t2\t3\t4\t5\t6\t7\t8\n",
            "not a number",
        ),
        ("empty.c3d", lambda: b"", "empty"),
    ],
)
def test_bad_recordings_give_one_line(name, content, words, tmp_path, cli_error):
    (tmp_path / name).write_bytes(content())
    err = cli_error(["measure", str(tmp_path / name), "--out", str(tmp_path / "o")])
    assert words in err
    assert not (tmp_path / "o").exists()


def test_an_unknown_label_names_the_option(synthetic, tmp_path, cli_error):
    _, _, path = synthetic
    err = cli_error(["measure", str(path), "--body", "x=B1_M1,B1_M2,NOPE", "--out", str(tmp_path / "o")])
    assert "--body" in err and "NOPE" in err
    err = cli_error(["measure", str(path), "--body", "x=B1_M1", "--out", str(tmp_path / "o")])
    assert "3 or more" in err


def test_the_c3d_reader_agrees_with_ezc3d(synthetic):
    """The bounded-memory reader against ezc3d's own reading of the same files."""
    from starforge.tracking.recording import read_c3d_ezc3d

    for path in (C3D, synthetic[2]):
        ours, theirs = read_recording(path), read_c3d_ezc3d(path)
        assert ours.labels == theirs.labels and ours.rate_hz == theirs.rate_hz
        assert np.array_equal(np.isnan(ours.points_mm), np.isnan(theirs.points_mm))
        assert np.array_equal(np.nan_to_num(ours.points_mm), np.nan_to_num(theirs.points_mm))


def test_a_recording_larger_than_the_memory_limit_is_refused_before_it_is_read(
    synthetic, cli_error, monkeypatch
):
    from starforge.runtime.budget import ENV_MEMORY

    monkeypatch.setenv(ENV_MEMORY, "1M")  # --max-memory sets it for the process: restored afterwards
    _, _, path = synthetic
    err = cli_error(["--max-memory", "1M", "measure", path, "--out", path.parent / "o"])
    assert "--max-memory" in err and "1,500 frames of 40 markers" in err
