"""`starforge stars` end to end: the paper's case under both rules, files, errors, determinism."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from starforge import load_family
from starforge.geometry.tetra import lengths_from_vertices
from starforge.stars.verify import check_family
from tests.conftest import FINGER, run_cli


def test_paper_case_face_rule_beats_200_and_verifies(finger_face):
    out, doc = finger_face
    assert len(doc["stars"]) >= 200
    assert check_family(doc) == []
    sm = doc["summary"]
    assert sm["upper_bound"] >= len(doc["stars"]) and sm["gap"] == sm["upper_bound"] - len(doc["stars"])


def test_paper_case_pair_rule_beats_25_and_verifies(finger_pair):
    out, doc = finger_pair
    assert len(doc["stars"]) >= 25
    assert check_family(doc) == []


def test_family_json_round_trips_and_csv_matches(finger_face):
    out, doc = finger_face
    fam = load_family(out / "family.json")
    assert fam.to_json()["stars"] == doc["stars"]
    assert load_family(out).spec == fam.spec  # a folder works too
    rows = list(csv.DictReader((out / "family.csv").read_text().splitlines()))
    assert len(rows) == len(fam)
    for row, star in zip(rows, fam.stars, strict=True):
        assert int(row["id"]) == star.id
        V = np.array([[float(row[f"{c}{i}"]) for c in "xyz"] for i in range(1, 5)])
        assert np.allclose(V, star.vertices, atol=1e-6)
        # the table's lengths are the distances between its own coordinates
        L = [float(row[k]) for k in ("u", "U", "v", "V", "w", "W")]
        assert np.allclose(lengths_from_vertices(V), L, atol=1e-5)


def test_every_star_fits_the_size_limit_with_its_spheres(finger_face):
    _, doc = finger_face
    limit = np.sort(doc["spec"]["box_mm"])
    d = doc["spec"]["marker_mm"]
    for s in doc["stars"]:
        V = np.array(s["vertices"])
        ext = np.array(s["obb"]["extents"])
        # the stored box really bounds the centres in the placement frame ...
        assert np.allclose(V.min(axis=0), [-ext[0] / 2, -ext[1] / 2, 0], atol=1e-6)
        assert np.allclose(V.max(axis=0), [ext[0] / 2, ext[1] / 2, ext[2]], atol=1e-6)
        # ... z is the longest side, y the shortest, and with one sphere diameter it fits the limit
        assert ext[2] >= ext[0] >= ext[1]
        assert (np.sort(ext) + d <= limit + 1e-6).all()


def test_margins_are_what_they_claim(finger_face):
    _, doc = finger_face
    tol_mm = doc["spec"]["delta_mm"]
    for s in doc["stars"]:
        L = sorted(s["lengths"].values())
        assert s["margins"]["internal_mm"] == pytest.approx(min(np.diff(L)))
        assert s["margins"]["family_face_mm"] >= tol_mm - 1e-9


@pytest.mark.slow
def test_same_spec_same_bytes(small_family, tmp_path):
    out, _ = small_family
    assert run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--out", tmp_path, "-q"]) == 0
    assert (tmp_path / "family.json").read_bytes() == (out / "family.json").read_bytes()
    assert (tmp_path / "family.csv").read_bytes() == (out / "family.csv").read_bytes()


@pytest.mark.slow
@pytest.mark.parametrize("rule", ["face", "pair"])
def test_the_cli_writes_the_finger_family_the_library_makes(rule, request, tmp_path):
    """``stars`` on the paper's finger case (warm-up, verification, staged output) writes the
    bytes of the library's family that the finger fixtures hold."""
    out, _ = request.getfixturevalue(f"finger_{rule}")
    assert run_cli(["stars", *FINGER, "--rule", rule, "--out", tmp_path, "-q"]) == 0
    for name in ("family.json", "family.csv"):
        assert (tmp_path / name).read_bytes() == (out / name).read_bytes()


def test_count_picks_n_and_refuses_the_impossible(small_family, tmp_path, capsys):
    _, doc = small_family
    n = len(doc["stars"])
    assert run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--count", 5, "--out", tmp_path / "a", "-q"]) == 0
    five = json.loads((tmp_path / "a" / "family.json").read_text())
    assert len(five["stars"]) == 5 and check_family(five) == []
    code = run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--count", n + 50, "--out", tmp_path / "b"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"count {n + 50} is not achievable" in err and "certified upper bound" in err
    assert not (tmp_path / "b").exists()


def test_greedy_and_covariance_options(tmp_path):
    args = ["stars", "--box", 16, 12, 24, "--delta", 2, "--select", "greedy", "--box-method", "covariance"]
    assert run_cli([*args, "--out", tmp_path, "-q"]) == 0
    doc = json.loads((tmp_path / "family.json").read_text())
    assert check_family(doc) == []
    assert {s["obb"]["method"] for s in doc["stars"]} == {"covariance"}


def test_template_spec_and_toml_path(tmp_path):
    toml = tmp_path / "tiny.toml"
    toml.write_text('box_mm = [16, 12, 24]\ndelta_mm = 2.0\nselect = "greedy"\n')
    assert run_cli(["stars", "--spec", toml, "--out", tmp_path / "o", "-q"]) == 0
    doc = json.loads((tmp_path / "o" / "family.json").read_text())
    assert doc["spec"]["name"] == "tiny" and doc["spec"]["select"] == "greedy"


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--box", 0, 12, 24], "--box's value 1 must be > 0"),
        (["--box", 20, -1, 24], "--box's value 2 must be > 0"),
        (["--box", 3, 3, 3], "too small for one 4.0 mm sphere"),
        (["--box", 20, 20, 20, "--delta", 8], "--delta 8.0 is too large"),
        (["--box", 20, 20, 20, "--delta", -1.5], "--delta must be > 0"),
        (["--box", 20, 20, 20, "--rule", "edge"], "rule must be one of face, pair"),
        (["--spec", "nosuchspec"], "--spec must be a template name or a TOML file, got 'nosuchspec'; known"),
        (["--box", 60, 60, 60, "--delta", 0.5], "1,489,131,909,720 labelled candidates"),
        (["--delta", "1e-310"], "--delta must be >= 0.001"),
        (["--tolerance", 1000], "--tolerance 1000 is too large"),
        (["--min-depth", 9], "--min-depth 9 leaves no star"),
        (["--name", "../x"], "--name must be"),
        (["--box", 16, 12, 24, "--delta", 2, "--count", 100000], "count 100000 is not achievable"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys, args, needle):
    out = tmp_path / "out"
    assert run_cli(["stars", *args, "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_unknown_toml_key_and_corrupt_toml(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("box_mm = [20, 20, 20]\ncolour = 'red'\n")
    assert run_cli(["stars", "--spec", bad, "--out", tmp_path / "o"]) == 2
    assert "unknown key 'colour'" in capsys.readouterr().err
    bad.write_text("box_mm = [20, 20,\n")
    assert run_cli(["stars", "--spec", bad, "--out", tmp_path / "o"]) == 2
    assert "not valid TOML" in capsys.readouterr().err


def test_existing_output_needs_force(small_family, capsys):
    out, _ = small_family
    before = (out / "family.json").read_bytes()
    assert run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--out", out]) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "family.json").read_bytes() == before


def test_load_family_rejects_other_versions_and_corrupt_files(small_family, tmp_path):
    from starforge.errors import StarforgeError

    _, doc = small_family
    p = tmp_path / "family.json"
    p.write_text(json.dumps({**doc, "version": 99}))
    with pytest.raises(StarforgeError, match="version 99"):
        load_family(p)
    p.write_text("{not json")
    with pytest.raises(StarforgeError, match="not valid JSON"):
        load_family(p)
    with pytest.raises(StarforgeError, match="not found"):
        load_family(tmp_path / "missing.json")


def test_finger_default_args_are_the_template():
    from starforge.catalog import load_template

    name, data = load_template("stars", "finger")
    assert name == "finger"
    assert [str(x) for x in data["box_mm"]] == FINGER[1:4]


@pytest.mark.slow
def test_preview_draws_a_png_sheet(tmp_path):
    args = ["stars", "--box", 16, 12, 24, "--delta", 2, "--select", "greedy", "--preview", "--out", tmp_path, "-q"]
    assert run_cli(args) == 0
    png = (tmp_path / "family.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert width > 400 and height > 200


@pytest.mark.slow
def test_family_made_under_a_preset_passes_that_presets_rules(tmp_path):
    fam = tmp_path / "art"
    args = ["stars", "--preset", "art", "--box", 70, 50, 80, "--marker", 10, "--select", "greedy", "--out", fam, "-q"]
    assert run_cli(args) == 0
    doc = json.loads((fam / "family.json").read_text())
    assert doc["spec"]["delta_mm"] == 5.0 and doc["spec"]["l_min_mm"] > 30.0
    assert len(doc["stars"]) >= 2 and check_family(doc) == []
    chk = tmp_path / "check"
    assert run_cli(["check", fam / "family.json", "--preset", "art", "--frames", 50, "--ghosts", 0, "--out", chk, "-q"]) == 0
    report = json.loads((chk / "check.json").read_text())
    assert report["rules"]["violations"] == []


def test_mount_reserves_its_room_and_every_body_fits(tmp_path):
    from starforge.cad.reserve import mount_reserve_mm

    fam = tmp_path / "fam"
    args = ["stars", "--box", 16, 12, 24, "--delta", 2, "--mount", "flat", "--select", "greedy", "--out", fam, "-q"]
    assert run_cli(args) == 0
    doc = json.loads((fam / "family.json").read_text())
    assert doc["spec"]["mount"] == "flat"
    assert doc["spec"]["reserve_mm"] == list(mount_reserve_mm("flat", 4.0))
    assert len(doc["stars"]) >= 3 and check_family(doc) == []
    # every printed body, mount included, fits the limit: export (the family's mount by default)
    # refuses any that does not
    code = run_cli(["export", fam / "family.json", "--format", "stl", "--no-plate", "--out", tmp_path / "b"])
    assert code == 0
    assert len(list((tmp_path / "b").glob("star_*.stl"))) == len(doc["stars"])
    # a manual reserve still overrides
    args = ["stars", "--box", 16, 12, 24, "--delta", 2, "--reserve", 3, 1.2, 3, "--out", tmp_path / "m", "-q"]
    assert run_cli(args) == 0
    assert json.loads((tmp_path / "m" / "family.json").read_text())["spec"]["reserve_mm"] == [3.0, 1.2, 3.0]


@pytest.mark.parametrize(
    "reserve,needle",
    [((-1, 0, 0), "--reserve's value 1 must be >= 0"), ((9, 0, 0), "leaves no room"), ((3, 12, 0), "out of order")],
)
def test_bad_reserve(tmp_path, capsys, reserve, needle):
    assert run_cli(["stars", "--box", 16, 12, 24, "--reserve", *reserve, "--out", tmp_path / "o"]) == 2
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_force_into_a_folder_where_a_target_is_a_directory_leaves_it_untouched(small_family, tmp_path, capsys):
    out = tmp_path / "fam"
    out.mkdir()
    (out / "run.json").write_text("old run\n")
    (out / "family.csv").mkdir()  # a folder where a file must go
    (out / "family.csv" / "keep.txt").write_text("mine\n")
    before = sorted((p.relative_to(out).as_posix(), p.read_bytes() if p.is_file() else None) for p in out.rglob("*"))
    code = run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, "--out", out, "--force", "-q"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "family.csv" in err
    after = sorted((p.relative_to(out).as_posix(), p.read_bytes() if p.is_file() else None) for p in out.rglob("*"))
    assert after == before  # no new family.json, the old run.json kept, the folder kept


@pytest.mark.parametrize(
    "edit,needle",
    [
        (lambda d: d["stars"][1].__setitem__("id", "two"), "stars[1].id must be an integer, got 'two'"),
        (lambda d: d["stars"][1]["lengths"].__setitem__("v", "x"), "stars[1] (id 2) has a value that is not a number"),
        (lambda d: d["stars"][1]["lengths"].pop("W"), "stars[1] (id 2) has no lengths.W"),
        (lambda d: d["stars"][0]["obb"].pop("transform"), "stars[0] (id 1) has no obb.transform"),
        (lambda d: d.__setitem__("units", "inch"), "gives units 'inch'"),
        (lambda d: d.pop("units"), "gives units None"),
        (lambda d: d["spec"].__setitem__("marker_mm", "big"), "spec: marker_mm must be a number"),
        (lambda d: d["stars"][0].__setitem__("vertices", [[0, 0, 0]] * 4), "fails verification: star 1"),
        (lambda d: d.__setitem__("stars", {"a": 1}), "stars must be a list"),
    ],
)
def test_family_json_is_re_verified_on_load_with_one_line_errors(small_family, tmp_path, edit, needle):
    import copy

    from starforge.errors import StarforgeError

    _, doc = small_family
    bad = copy.deepcopy(doc)
    edit(bad)
    p = tmp_path / "family.json"
    p.write_text(json.dumps(bad))
    with pytest.raises(StarforgeError) as exc:
        load_family(p)
    assert needle in str(exc.value) and "\n" not in str(exc.value)


def test_family_json_with_spec_keys_left_out_loads_or_says_so_in_one_line(small_family, tmp_path):
    """A spec key left out falls back to the spec's default (or is refused in one line); the
    verification sees the defaults too, never a KeyError."""
    import copy

    from starforge.errors import StarforgeError

    _, doc = small_family
    for key in doc["spec"]:
        bad = copy.deepcopy(doc)
        del bad["spec"][key]
        p = tmp_path / f"no_{key}.json"
        p.write_text(json.dumps(bad))
        try:
            fam = load_family(p)
        except StarforgeError as exc:
            assert "\n" not in str(exc)
        else:
            assert len(fam.stars) == len(doc["stars"])


def test_nearest_face_distances_match_a_kd_tree():
    """margins' nearest other face (numpy, in blocks: 1500 faces make three) gives the very
    numbers a k-d tree query does, ties and repeated faces included."""
    from scipy.spatial import cKDTree

    from starforge.stars.family import _nearest_other_chebyshev

    rng = np.random.default_rng(2)
    for m in (2, 7, 600, 1500):
        F = np.sort(np.round(rng.uniform(5, 40, (m, 3)) * 2) / 2, axis=1)
        want = cKDTree(F).query(F, k=2, p=np.inf)[0][:, 1]
        assert np.array_equal(_nearest_other_chebyshev(F), want)


def test_pair_margins_match_the_24_relabelled_forms_one_by_one():
    """margins' pair margin (shared "both differ" amounts per opposite-pair image) is, bit for
    bit, the plain definition: over other stars j and the 24 relabellings of j, the smallest
    of the largest min(|a_k - b_k|, |A_k - B_k|) over the three opposite pairs k."""
    from starforge.geometry.tetra import RELABELLINGS
    from starforge.stars.family import _pair_margins

    rng = np.random.default_rng(4)
    for n in (2, 5, 60):
        L = np.round(rng.uniform(8, 40, (n, 6)) * 4) / 4  # repeated lengths: ties included
        want = np.full(n, np.inf)
        for i in range(n):
            for j in range(n):
                if i != j:
                    for r in RELABELLINGS:
                        d = np.abs(L[i] - L[j, r])
                        want[i] = min(want[i], max(min(d[2 * k], d[2 * k + 1]) for k in range(3)))
        assert np.array_equal(_pair_margins(L), want)
