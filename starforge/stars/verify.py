"""An independent brute-force checker for a written family (reads the raw family.json data).

It shares no code with the generator beyond numpy: lengths come from the stored vertices,
faces from explicit vertex triples, relabellings from ``itertools.permutations``, and the fit
from the stored box.  It returns a list of problems (empty when the family is sound).
"""

from __future__ import annotations

import itertools

import numpy as np

_FACES = [(0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)]
# opposite edge pairs as vertex pairs: (AB, CD), (BC, AD), (AC, BD)
_PAIRS = [((0, 1), (2, 3)), ((1, 2), (0, 3)), ((0, 2), (1, 3))]


#: bytes of one block of face differences (the pairwise face check runs in blocks of rows)
BLOCK_BYTES = 1e6
#: seconds per star and per pair of stars of :func:`check_family`, calibrated on a loaded 2-core
#: x86_64 (a high estimate on a quiet machine)
SECONDS_PER_STAR, SECONDS_PER_PAIR = 1e-3, 2e-6


def verify_seconds(n_stars: int) -> float:
    """Rough wall time of :func:`check_family` for ``n_stars`` stars, s (quadratic in them)."""
    return SECONDS_PER_STAR * n_stars + SECONDS_PER_PAIR * n_stars * n_stars


def _star_checks(V: np.ndarray, stars: list, slack_mm: float) -> dict:
    """The per-star quantities of :func:`check_family` for stars (n, 4, 3), computed from the
    vertices alone: edge lengths (u, U, v, V, w, W), the six sorted, the depth (smallest
    vertex-face height or opposite-edge distance), each face's sorted sides, whether the
    vertices lie in the stored box and whether the stored transform is a proper rotation."""
    n = len(V)
    edges = [(0, 1), (2, 3), (1, 2), (0, 3), (0, 2), (1, 3)]  # u, U, v, V, w, W
    edge = np.stack([np.linalg.norm(V[:, a] - V[:, b], axis=-1) for a, b in edges], axis=1).reshape(n, 6)
    pairs = list(itertools.combinations(range(4), 2))
    dist = np.stack([np.linalg.norm(V[:, a] - V[:, b], axis=-1) for a, b in pairs], axis=1).reshape(n, 6)
    heights = []
    for a, b, c in _FACES:
        (d,) = {0, 1, 2, 3} - {a, b, c}
        nrm = np.cross(V[:, b] - V[:, a], V[:, c] - V[:, a])
        dot = np.abs(np.einsum("ij,ij->i", V[:, d] - V[:, a], nrm))
        heights.append(dot / np.maximum(np.linalg.norm(nrm, axis=-1), 1e-300))
    for (a, b), (c, d) in _PAIRS:
        nrm = np.cross(V[:, b] - V[:, a], V[:, d] - V[:, c])
        nn = np.linalg.norm(nrm, axis=-1)
        dot = np.abs(np.einsum("ij,ij->i", V[:, c] - V[:, a], nrm))
        heights.append(np.where(nn > 1e-12, dot / np.where(nn > 1e-12, nn, 1.0), np.inf))
    faces = np.sort(
        np.stack(
            [
                np.stack([np.linalg.norm(V[:, a] - V[:, b], axis=-1), np.linalg.norm(V[:, b] - V[:, c], axis=-1),
                          np.linalg.norm(V[:, a] - V[:, c], axis=-1)], axis=-1)
                for a, b, c in _FACES
            ],
            axis=1,
        ).reshape(n, 4, 3),
        axis=2,
    )
    ext = np.array([np.asarray(s["obb"]["extents"], dtype=float) for s in stars]).reshape(n, 3)
    lo = np.stack([-ext[:, 0] / 2, -ext[:, 1] / 2, np.zeros(n)], axis=1)[:, None] - slack_mm
    hi = np.stack([ext[:, 0] / 2, ext[:, 1] / 2, ext[:, 2]], axis=1)[:, None] + slack_mm
    inside = ((V >= lo) & (V <= hi)).all(axis=(1, 2))
    R = np.array([np.asarray(s["obb"]["transform"], dtype=float)[:3, :3] for s in stars]).reshape(n, 3, 3)
    # np.allclose(R R^T, I, atol=1e-7) per star (its default rtol 1e-5 on the diagonal)
    orth = (np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)) <= 1e-7 + 1e-5 * np.eye(3)).all(axis=(1, 2))
    rotation = orth & (np.abs(np.linalg.det(R) - 1) < 1e-7) if n else np.zeros(0, bool)
    return {
        "edge": edge,
        "sorted": np.sort(dist, axis=1),
        "depth": np.min(np.stack(heights, axis=1), axis=1) if n else np.zeros(0),
        "faces": faces,
        "ext": ext,
        "inside": inside,
        "rotation": rotation,
    }


def check_family(data: dict, slack_mm: float = 1e-6) -> list[str]:
    """Re-check a family.json mapping: edges, faces, the rule across the family, and the fit."""
    spec = data["spec"]
    delta = float(spec["delta_mm"])
    tol_mm = float(spec["tolerance_mm"]) if spec.get("tolerance_mm") is not None else delta
    marker = float(spec["marker_mm"])
    # version 2 families keep the tolerance within a star and a face too, and a minimum depth
    version = int(data.get("version", 1))
    within = tol_mm if version >= 2 else delta
    depth = spec.get("min_depth_mm")
    depth = (marker / 2 if depth is None else float(depth)) if version >= 2 else 0.0
    limit = sorted(float(b) for b in spec["box_mm"])
    reserve = [float(r) for r in (spec.get("reserve_mm") or (0.0, 0.0, 0.0))]  # kept free for a mount
    rule = spec.get("rule", "face")
    problems: list[str] = []
    stars = data["stars"]
    names = ["u", "U", "v", "V", "w", "W"]
    # the per-star checks run on every star at once (numpy over the stars), then report in star
    # order, so a family of hundreds is checked in milliseconds
    ok, Ps = [], []
    for s in stars:
        P = np.asarray(s["vertices"], dtype=float)
        good = P.shape == (4, 3) and bool(np.isfinite(P).all()) and float(np.abs(P).max()) <= 1e5
        ok.append(good)
        if good:
            Ps.append(P)
    V = np.array(Ps).reshape(-1, 4, 3)
    checks = _star_checks(V, [s for s, g in zip(stars, ok, strict=True) if g], slack_mm)
    faces_all = []  # (star id, face index, sorted sides)
    k = 0
    for s, good in zip(stars, ok, strict=True):
        sid = s["id"]
        if not good:
            P = np.asarray(s["vertices"], dtype=float)
            if P.shape != (4, 3):
                problems.append(f"star {sid}: vertices are not 4 x 3")
            else:
                problems.append(f"star {sid}: vertices are not finite coordinates within 100 m")
            continue
        c = {key: val[k] for key, val in checks.items()}
        k += 1
        # 1. stored lengths match the vertices
        for j, name in enumerate(names):
            d = float(c["edge"][j])
            if abs(d - float(s["lengths"][name])) > slack_mm:
                problems.append(f"star {sid}: |{name}| is {d:.6f} mm at the vertices, {s['lengths'][name]} stored")
        # 2. all six lengths differ by >= the tolerance (delta for version 1 files)
        ls = c["sorted"]
        for a, b in itertools.pairwise(ls.tolist()):
            if b - a < within - slack_mm:
                problems.append(f"star {sid}: two edge lengths differ by {b - a:.6f} mm < {within} mm")
        # 2b. deep enough: the smallest width over directions, brute force over the candidates of
        # a tetrahedron (vertex-face heights and opposite-edge distances)
        if depth > 0 and c["depth"] < depth - slack_mm:
            problems.append(f"star {sid}: depth {c['depth']:.4f} mm < min_depth {depth} mm")
        # 3. spheres do not overlap
        if ls[0] < marker - slack_mm:
            problems.append(f"star {sid}: two sphere centres are {ls[0]:.4f} mm apart (< marker {marker})")
        # 4. every face is scalene
        for fi in range(4):
            sides = c["faces"][fi].tolist()
            if min(sides[1] - sides[0], sides[2] - sides[1]) < within - slack_mm:
                problems.append(f"star {sid}: face {fi} is not scalene")
            faces_all.append((sid, fi, sides))
        # 5. the fit: vertices inside the stored box (placement frame), box + one marker inside the limit
        if not c["inside"]:
            problems.append(f"star {sid}: a sphere centre lies outside its reported box")
        ext = c["ext"]
        phys = sorted(float(e) + marker for e in ext)
        phys = [p + r for p, r in zip(phys, reserve, strict=True)]
        for e, lim in zip(phys, limit, strict=True):
            if e > lim + slack_mm:
                problems.append(f"star {sid}: box {phys} (with spheres) does not fit the limit {limit}")
                break
        if not c["rotation"]:
            problems.append(f"star {sid}: obb transform is not a proper rotation")
    # 6. the rule across the family (vectorised over pairs; the relabellings come from itertools)
    if rule == "face":
        F = np.array([f[2] for f in faces_all]).reshape(-1, 3)  # (4n, 3)
        # every pair, in blocks of rows (bounded memory, and small enough to stay in the CPU's
        # cache): the largest of the three side differences, one side at a time
        rows = max(16, int(BLOCK_BYTES // (len(F) * 8)))
        for lo in range(0, len(F), rows):
            d = np.abs(F[lo : lo + rows, None, 0] - F[None, :, 0])
            for k in (1, 2):
                np.maximum(d, np.abs(F[lo : lo + rows, None, k] - F[None, :, k]), out=d)
            d[np.arange(len(d)), lo + np.arange(len(d))] = np.inf
            bad = np.argwhere(d < tol_mm - slack_mm)
            for a, b in bad:
                if lo + a < b and len(problems) < 40:
                    i, fi, _ = faces_all[lo + a]
                    j, fj, _ = faces_all[b]
                    problems.append(
                        f"faces {i}/{fi} and {j}/{fj} differ by less than {tol_mm} mm in every side"
                    )
    else:
        V = np.array([np.asarray(s["vertices"], dtype=float) for s in stars])  # (n, 4, 3)
        perms = list(itertools.permutations(range(4)))
        flat = [e for pair in _PAIRS for e in pair]  # 6 edges as vertex pairs, pair-major

        def pair_lengths(X):  # (n, 4, 3) -> (n, 3, 2)
            return np.stack([np.linalg.norm(X[:, a] - X[:, b], axis=-1) for a, b in flat], axis=1).reshape(
                -1, 3, 2
            )

        base = pair_lengths(V)  # (n, 3, 2)
        forms = np.stack([pair_lengths(V[:, list(p)]) for p in perms], axis=1)  # (n, 24, 3, 2)
        for i in range(len(stars)):
            d = np.abs(base[i][None, None] - forms)  # (n, 24, 3, 2)
            both = (d >= tol_mm - slack_mm).all(axis=3).any(axis=2)  # some pair differs in both lengths
            apart = both.all(axis=1)  # ... under every relabelling
            apart[: i + 1] = True
            for j in np.flatnonzero(~apart)[:5]:
                problems.append(
                    f"stars {stars[i]['id']} and {stars[j]['id']} are not told apart by any opposite pair"
                )
    return problems
