"""Four-marker rigid bodies (a lab's tools, measured bodies) as a ``family.json`` that every
family command takes (``export`` prints them, ``check``, ``convert`` and ``--avoid`` read them).

A family file holds stars of 4 markers A, B, C, D (the bodies' marker order) in the family
paper's placement frame (:func:`starforge.stars.boxes.place_stars`), and a spec whose limits the
stars meet: the box is the largest star's minimum-volume box plus one marker, the tolerance the
smallest difference the bodies keep (within a star: edges and face sides; across stars: faces,
the face rule's margin).  The file is verified as any family file is
(:func:`starforge.stars.model.family_from_json`) before it is returned.  Each star also carries
the body's ``name``, its ``marker_names`` and, for a measured body, ``scatter_mm`` (each
marker's RMS distance from its place over the recording's frames).
"""

from __future__ import annotations

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.rigid import default_tip_mm
from starforge.geometry.tetra import face_sides, tetra_width
from starforge.stars.boxes import place_stars
from starforge.stars.family import accuracy, margins
from starforge.stars.model import Family, Star, family_from_json
from starforge.stars.spec import StarSpec

#: the smallest tolerance a family file states, mm (the spec's smallest length variation)
MIN_TOLERANCE_MM = 1e-3
#: room added to the box so the stars sit inside it after the file's 1e-9 mm rounding, mm
BOX_SLACK_MM = 1e-3
_EDGES = [(0, 1), (2, 3), (1, 2), (0, 3), (0, 2), (1, 3)]  # u, U, v, V, w, W


def star_lengths(V: np.ndarray) -> np.ndarray:
    """Edge lengths (n, 6) (u=AB, U=CD, v=BC, V=AD, w=AC, W=BD) of stars (n, 4, 3), mm."""
    return np.stack([np.linalg.norm(V[:, a] - V[:, b], axis=-1) for a, b in _EDGES], axis=1)


def kept_difference_mm(L: np.ndarray) -> float:
    """The smallest difference stars (n, 6) keep: between two edges of a star, two sides of a
    face, and (face rule) any two faces of the family, mm."""
    within = np.diff(np.sort(L, axis=1), axis=1).min()
    F = np.sort(face_sides(L), axis=2)  # (n, 4, 3)
    scalene = np.diff(F, axis=2).min()
    across = min((m["family_face_mm"] for m in margins(L, pair=False)), default=np.inf)
    return float(min(within, scalene, across))


def family_from_bodies(
    bodies,
    name: str = "bodies",
    marker_mm: float | None = None,
    noise_mm: float = 0.2,
    description: str = "",
    extra: list[dict] | None = None,
    mount: str | None = None,
    reserve_for=None,
) -> dict:
    """family.json data of ``bodies``: (name, (4, 3) mm, marker names or None) each.

    ``marker_mm``: the marker diameter (None: 4 mm, or less when two markers are closer);
    ``extra``: one dict per body merged into its star (e.g. ``scatter_mm``); ``mount``: the
    mount the bodies are to be printed with, and ``reserve_for(marker_mm) -> (3,) mm`` the room
    it takes of the box's sorted sides (:func:`starforge.cad.reserve.mount_reserve_mm`), added
    to the box so that ``starforge export`` builds every body within it.  Raises
    StarforgeError (one line) for a body that is no 4-marker star or bodies a family cannot
    hold apart (two equal edges or faces)."""
    bodies = list(bodies)
    if not bodies:
        raise StarforgeError("no body to write as a family")
    for bname, P, _ in bodies:
        if np.shape(P) != (4, 3):
            raise StarforgeError(
                f"a family.json holds 4-marker stars; {bname} has {len(P)} markers (choose a tracker --format)"
            )
    V = np.array([np.asarray(P, dtype=float) for _, P, _ in bodies])
    L = star_lengths(V)
    kept = kept_difference_mm(L)
    if not kept >= MIN_TOLERANCE_MM:
        raise StarforgeError(
            f"these bodies keep only {kept:.4g} mm between two edges or faces; a family.json needs "
            f">= {MIN_TOLERANCE_MM} mm (choose a tracker --format)"
        )
    tolerance = float(np.floor(kept / MIN_TOLERANCE_MM) * MIN_TOLERANCE_MM)
    shortest = float(L.min())
    marker = min(4.0 if marker_mm is None else float(marker_mm), shortest)
    placed = place_stars(V, [1e9] * 3)
    ext = np.array([sorted(item[2]) for item in placed])
    reserve = tuple(float(r) for r in (reserve_for(marker) if reserve_for else (0.0, 0.0, 0.0)))
    box = tuple(float(x) for x in (ext.max(axis=0) + marker + np.array(reserve) + BOX_SLACK_MM))
    spec = StarSpec(
        box_mm=box,
        marker_mm=marker,
        delta_mm=tolerance,
        tolerance_mm=tolerance,
        l_min_mm=marker,
        min_depth_mm=0.0,
        noise_mm=noise_mm,
        reserve_mm=reserve,
        mount=mount,
        name=name,
        description=description or "rigid bodies read or measured by starforge (not enumerated)",
    )
    tip = default_tip_mm(spec.box_mm)
    acc = accuracy(np.array([item[0] for item in placed]), tip, noise_mm)
    marg = margins(L, pair=False)
    depth = tetra_width(L)
    stars = [
        Star(k + 1, L[k], Vk, e, T, how, marg[k], min_ext, float(depth[k]), acc[k])
        for k, (Vk, T, e, how, _, min_ext) in enumerate(placed)
    ]
    summary = {
        "size": len(stars),
        "rule": "face",
        "tolerance_mm": tolerance,
        "tip_mm": [float(x) for x in tip],
        "noise_mm": noise_mm,
        "origin": "bodies",
    }
    data = Family(spec=spec, stars=tuple(stars), summary=summary).to_json()
    for k, (bname, _, mnames) in enumerate(bodies):
        data["stars"][k]["name"] = str(bname)
        if mnames:
            data["stars"][k]["marker_names"] = [str(m) for m in mnames]
        data["stars"][k].update((extra or [{}] * len(bodies))[k])
    family_from_json(data, where=f"the family of {name}")  # verified as any family file
    return data
