"""Where people hold a prop, as a distribution of grips that a layout is scored under.

The graspable part is found from the prop's shape: along each of its principal axes (the
eigenvectors of the covariance of its vertices, longest spread first) and each axis of its own
frame (a handle set square to a tilted body, as on a drill) the mesh is cut every
:data:`starforge.props.hand.SLICE_M`; a section is *graspable* when a hand closes around it,
its wider principal width within :data:`GRASP_WIDTH_M` (20-55 mm, what a fist closes round)
and its narrower at least :data:`GRASP_THICK_M` (a blade or a plate is none).  The longest run of consecutive graspable
sections, at least :data:`GRASP_RUN_M` long, is the handle or the neck that is held; a prop
with none is held by its body, the longest run of sections up to :data:`BODY_WIDTH_M` wide
(the wider width of a square section lies between its side and its diagonal).
A prop without one is held where :func:`starforge.props.hand.grip_segment` says (its thinnest
end), and a prop shorter than :data:`starforge.props.hand.PINCH_BELOW_M` is pinched there
(:func:`starforge.props.hand.pinch`).

People do not only hold the part a shape suggests: they choke up on a handle onto the shaft
or the throat beyond it, grab a torch by its head or a bottle by its body.  The *reach* is the
held run continued along its axis over every section a hand spans (up to :data:`BODY_WIDTH_M`
wide, however thin), and the distribution (:func:`grip_distribution`) spreads the palm
(:data:`starforge.props.hand.PALM_M` long, or the reach's length) evenly along the reach, as
many places as keep neighbouring palms at most :data:`STEP` of a palm apart (at least two, at
most :data:`POSITIONS`), by either hand, with the back of the hand and the wrist at :data:`WRAPS`
angles around the part; the wraps take turns along a grid as many times finer, so the grips
stand for a hand anywhere along the reach, not at a few places with every wrap at each.  Each
grip is a set of capsules that move with the prop (:func:`hand_model`): the fist around the
widest section under the palm (:func:`starforge.props.hand.fist`) and the wrist and forearm, a
capsule of :data:`WRIST_M` radius and :data:`FOREARM_M` length leaving the part's surface at the wrap
angle, turned :data:`THUMB_DEG` towards the thumb's side (a left hand is the mirror image of a
right one, so the turn changes sign).  Every pose of the optimizer's sample is held in one grip
of the distribution, the same number of poses per grip in a random order drawn from the run's
seed (:func:`assign_grips`): the tracked fraction then is the expectation over the grips, and a
marker inside a grip's fist is lost in that grip's poses (no sight line leaves the hand).  A
site is *under the hand*, and no marker goes there, when the fists (or the fingertips) of more
than :data:`HELD_SHARE` of the grips cover it (of the one grip, when only one is assumed): where
people hold the prop most, a marker is knocked off or hidden.  A site fewer grips cover stays a
candidate, and a layout is ranked by how it is tracked whichever of them holds the prop.
Along the other directions the mesh is cut in, a stretch at least a palm long whose sections a
hand spans (a drill's body beside its handle, where the other hand steadies it) gets grips of
its own in the same way (:attr:`HeldPart.others`; of stretches along one place, the slimmest).

A prop with a handle (a loop round a see-through opening, :func:`starforge.props.handle.find_handle`:
a mug, a jug, a bucket) is held by the handle in :data:`HANDLE_SHARE` of the poses, a fist round
its bar with the fingers through the opening, by either hand, the wrist at :data:`HANDLE_WRAPS`
away from the body (:func:`handle_grips`), and wrapped round its body (the held part of the mesh
without the handle, as above) in the others: each grip carries a weight (:attr:`Grip.weight`)
that shares out the poses and counts in the under-the-hand rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.distance import point_segment_distance
from starforge.geometry.frames import perpendicular_basis
from starforge.props.hand import (
    CAPSULE_COLUMNS,
    PALM_M,
    PINCH_BELOW_M,
    SLICE_M,
    Capsule,
    capsule_arrays,
    fist,
    grip_segment,
    inside_capsules,
    parse_grip,
    pinch,
    section_widths_of,
)
from starforge.props.handle import Handle, find_handle, without_handle

#: a graspable section's wider principal width, m (a fist closes all round 20-55 mm)
GRASP_WIDTH_M = (0.02, 0.055)
#: a prop without such a handle is held by its body where it is at most this wide (m; a hand
#: spans a 70 mm carton or a 75 mm bottle, not a 100 mm box)
BODY_WIDTH_M = 0.1
#: a graspable section's narrower width is at least this, m (thinner: a blade or a plate)
GRASP_THICK_M = 0.012
#: the held run is at least this long, m
GRASP_RUN_M = 0.04
#: at most this many sections along an axis (:data:`starforge.props.hand.SLICE_M` apart)
MAX_SLICES = 400
#: at most this many palm positions along the reach (one when the reach is hardly longer than the palm)
POSITIONS = 13
#: neighbouring palm positions are at most this many palm widths apart: a hand may hold anywhere
#: between, and a spot near a palm's end is then covered by about the share of the grips that a
#: hand held uniformly along the reach would cover it in (at half a palm apart, a spot between two
#: positions counts as covered by neither)
STEP = 0.25
#: angles around the part where the back of the hand and the wrist sit, degrees: close enough
#: that no gap between two forearms is left for a layout to hide markers in
WRAPS = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)
#: the wrist and forearm: radius and length, m (a wrist is 50-65 mm across)
WRIST_M = 0.03
FOREARM_M = 0.25
#: the wrist leaves the part turned this far (degrees) from the radial direction, towards the thumb
THUMB_DEG = 20.0
#: a prop with a handle (:mod:`starforge.props.handle`) is held by it in this share of the poses,
#: by its body (wrapped round the rest of the prop) in the others
HANDLE_SHARE = 0.8
#: angles around a handle's bar where the back of the hand and the wrist sit, degrees from the
#: direction away from the body (the body blocks the other side)
HANDLE_WRAPS = (-45.0, 0.0, 45.0)


@dataclass(frozen=True)
class Grip:
    """One way of holding the prop.

    Attributes
    ----------
    label : str
        What a person reads: the hand, where along the part, the wrap.
    hand : str
        ``"right"``, ``"left"``, or ``""`` for a pinch or a pinned grip.
    along : float
        The palm's centre along the reach (:attr:`HeldPart.reach`), 0 (one end) to 1 (the other).
    wrap_deg : float
        Angle around the part of the back of the hand, degrees.
    capsules : tuple of Capsule
        The hand in the prop frame, m; the first is the fist (or fingertips) on the surface, the
        others only hide what lies behind them.
    weight : float
        How often the prop is held so, relative to the other grips (the poses are shared out in
        proportion, :func:`assign_grips`).
    on_handle : bool
        The fist closes round a handle's bar (:func:`handle_grips`).
    """

    label: str
    hand: str
    along: float
    wrap_deg: float
    capsules: tuple[Capsule, ...]
    weight: float = 1.0
    on_handle: bool = False

    def to_json(self) -> dict:
        return {
            "label": self.label,
            "hand": self.hand,
            "along": round(float(self.along), 4),
            "wrap_deg": round(float(self.wrap_deg), 3),
            "capsules": [c.to_json() for c in self.capsules],
            **({"weight": round(float(self.weight), 6)} if self.weight != 1.0 else {}),
            **({"on_handle": True} if self.on_handle else {}),
        }


@dataclass(frozen=True)
class HeldPart:
    """The part people hold: a run along one of the prop's axes (prop frame, m).

    ``a``, ``b``: the run's ends on the axis through the sections' centres; ``radius_m``: half
    its widest section; ``found``: from the sections (False: the thinnest-end fallback).
    ``reach_a``, ``reach_b``: the stretch of that axis a hand may hold, the run continued over
    every section up to :data:`BODY_WIDTH_M` wide (a torch's head, a screwdriver's shaft, a
    racket's throat; the run itself when none is found); ``reach_radii``: half the wider width
    of its sections, evenly spaced from ``reach_a`` to ``reach_b`` (empty: ``radius_m`` all along).
    ``others``: the stretches along the other directions the mesh is cut in that a hand spans over
    at least a palm (a drill's body beside its handle), each its own reach.  ``handle``: the
    prop's handle (:func:`starforge.props.handle.find_handle`), when it has one; the rest of the
    part is then its body without the handle.
    """

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius_m: float
    found: bool
    reach_a: tuple[float, float, float] | None = None
    reach_b: tuple[float, float, float] | None = None
    reach_radii: tuple[float, ...] = ()
    others: tuple[HeldPart, ...] = ()
    handle: Handle | None = None

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(np.subtract(self.b, self.a)))

    @property
    def reach(self) -> tuple[np.ndarray, np.ndarray]:
        """The ends of the stretch a hand may hold, (3,) each, m."""
        if self.reach_a is None or self.reach_b is None:
            return np.asarray(self.a, float), np.asarray(self.b, float)
        return np.asarray(self.reach_a, float), np.asarray(self.reach_b, float)

    def radius_between(self, t0: float, t1: float) -> float:
        """Half the widest section between ``t0`` and ``t1`` (m from ``reach_a`` along the reach)."""
        a, b = self.reach
        r = np.asarray(self.reach_radii, float)
        if not len(r):
            return self.radius_m
        t = np.linspace(0.0, float(np.linalg.norm(b - a)), len(r))
        inside = r[(t >= t0 - 1e-9) & (t <= t1 + 1e-9)]
        return float(inside.max()) if len(inside) else self.radius_m

    def to_json(self) -> dict:
        a, b = self.reach
        return {
            "a": [round(float(x), 6) + 0.0 for x in self.a],
            "b": [round(float(x), 6) + 0.0 for x in self.b],
            "width_mm": round(2000 * self.radius_m, 1),
            "length_mm": round(1000 * self.length_m, 1),
            "from_sections": self.found,
            "reach_a": [round(float(x), 6) + 0.0 for x in a],
            "reach_b": [round(float(x), 6) + 0.0 for x in b],
            "reach_length_mm": round(1000 * float(np.linalg.norm(b - a)), 1),
            **({"others": [o.to_json() for o in self.others]} if self.others else {}),
            **({"handle": self.handle.to_json()} if self.handle is not None else {}),
        }


def principal_axes(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The centroid (3,) and the principal axes (3, 3), one per row, largest spread first."""
    v = np.asarray(vertices, float)
    c = v.mean(axis=0)
    w, vecs = np.linalg.eigh(np.cov((v - c).T) + 1e-18 * np.eye(3))
    axes = vecs[:, np.argsort(-w, kind="stable")].T
    for k in range(3):  # a sign convention: the largest component positive (deterministic)
        if axes[k][np.argmax(np.abs(axes[k]))] < 0:
            axes[k] = -axes[k]
    return c, axes


def _runs(ok: np.ndarray):
    """(start, stop) of every run of consecutive true values."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], ok, [False]]).astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def cut_directions(vertices: np.ndarray) -> list[np.ndarray]:
    """The directions the mesh is cut square to: its principal axes, then the file's own axes
    more than 10 degrees from those already taken, (3,) unit vectors."""
    _, principal = principal_axes(vertices)
    dirs: list[np.ndarray] = []
    for d in [*principal, *np.eye(3)]:
        if all(abs(float(d @ q)) < math.cos(math.radians(10.0)) for q in dirs):
            dirs.append(d)
    return dirs


def held_part(mesh, fallback=None) -> HeldPart:
    """The longest graspable run of the mesh (see the module docstring); else ``fallback``
    (``(a, b, part_radius)``, a built-in prop's own grip) or the mesh's thinnest end."""
    v = np.asarray(mesh.vertices, float)
    e = np.asarray(mesh.edges_unique, int)
    c, _ = principal_axes(v)
    slices = []
    for d in cut_directions(v):
        axes = np.array([d, *perpendicular_basis(d)])
        local = (v - c) @ axes.T  # along d first
        lo, hi = local[:, 0].min(), local[:, 0].max()
        if hi - lo < GRASP_RUN_M:
            continue
        n = int(min(MAX_SLICES, max(10, (hi - lo) // SLICE_M)))
        step = (hi - lo) / n
        h = lo + (np.arange(n) + 0.5) * step
        slices.append((axes, h, section_widths_of(local, e, 0, h), step))
    best = None
    for widest in (GRASP_WIDTH_M[1], BODY_WIDTH_M):  # a handle first, else a body
        for axes, h, w, step in slices:
            ok = (w[:, 0] >= GRASP_WIDTH_M[0]) & (w[:, 0] <= widest) & (w[:, 1] >= GRASP_THICK_M)
            for i, j in _runs(ok):
                length = (j - i) * step
                if length >= GRASP_RUN_M - 1e-12 and (best is None or length > best[0] + 1e-9):
                    best = (length, axes, i, j, h, w, step)
        if best is not None:
            break
    if best is None:
        a, b, r = grip_segment(mesh) if fallback is None else fallback
        return HeldPart(tuple(map(float, a)), tuple(map(float, b)), float(r), False)
    length, axes, i, j, h, w, step = best
    mid = np.nanmean(w[i:j, 2:], axis=0)

    def at(t):
        return tuple(c + np.array([t, *mid]) @ axes)

    i0, j0 = _reach(w, i, j)
    reach = (at(h[i0] - step / 2), at(h[j0 - 1] + step / 2))
    found = [p for p in (_other_part(c, s) for s in slices if s[0] is not axes) if p is not None]
    others: list[HeldPart] = []
    kept = [(np.asarray(reach[0]), np.asarray(reach[1]), 0.0)]  # reaches taken: ends, and the part's half width
    for p in sorted(found, key=lambda p: (p.radius_m, -p.length_m)):  # of those along one stretch, the slimmest
        centre = (np.asarray(p.a) + np.asarray(p.b)) / 2
        if all(point_segment_distance(centre[None], qa, qb)[0] > p.radius_m + qr for qa, qb, qr in kept):
            others.append(p)
            kept.append((*p.reach, p.radius_m))
    return HeldPart(
        at(h[i] - step / 2), at(h[j - 1] + step / 2), float(np.nanmax(w[i:j, 0]) / 2), True,
        *reach, tuple(float(x) / 2 for x in w[i0:j0, 0]), tuple(others),
    )  # fmt: skip


def _spannable(w: np.ndarray) -> np.ndarray:
    """Which sections (widths ``w``, :func:`section_widths_of`) the plane cuts and a hand spans
    (at most :data:`BODY_WIDTH_M` wide)."""
    return np.isfinite(w[:, 0]) & (w[:, 0] <= BODY_WIDTH_M)


def _other_part(c: np.ndarray, sliced) -> HeldPart | None:
    """The longest run, at least a palm long, of sections up to :data:`BODY_WIDTH_M` wide along one
    more direction (``sliced``: its axes, heights, widths and step; ``c`` the frame's origin):
    where a second hand, or the one hand, may also hold the prop; None when there is none."""
    axes, h, w, step = sliced
    runs = [(j - i, i, j) for i, j in _runs(_spannable(w)) if (j - i) * step >= PALM_M - 1e-12]
    if not runs:
        return None
    _, i, j = max(runs)
    mid = np.nanmean(w[i:j, 2:], axis=0)
    a, b = (tuple(c + np.array([t, *mid]) @ axes) for t in (h[i] - step / 2, h[j - 1] + step / 2))
    return HeldPart(a, b, float(np.nanmax(w[i:j, 0]) / 2), True, a, b, tuple(float(x) / 2 for x in w[i:j, 0]))


def _reach(w: np.ndarray, i: int, j: int) -> tuple[int, int]:
    """The run ``i:j`` of sections (widths ``w``, :func:`section_widths_of`) continued both ways
    over every section the plane cuts that is at most :data:`BODY_WIDTH_M` wide."""
    ok = _spannable(w)
    while i > 0 and ok[i - 1]:
        i -= 1
    while j < len(w) and ok[j]:
        j += 1
    return i, j


def hand_model(a, b, part_radius: float, wrap_deg: float, hand: str, toward=None) -> tuple[Capsule, Capsule]:
    """A hand holding the part ``a``-``b`` (the stretch the palm covers, m) of ``part_radius``:
    the fist (:func:`starforge.props.hand.fist`) and the wrist leaving the part at
    ``wrap_deg`` around it, turned :data:`THUMB_DEG` towards the thumb (``hand``: right or left);
    ``wrap_deg`` 0 is ``toward`` (a (3,) direction square to the part) when given."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    u = (b - a) / max(float(np.linalg.norm(b - a)), 1e-12)
    if toward is None:
        e1, e2 = perpendicular_basis(u)
    else:
        e1 = np.cross(np.cross(u, np.asarray(toward, float)), u)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(u, e1)
    phi = math.radians(wrap_deg)
    radial = math.cos(phi) * e1 + math.sin(phi) * e2
    tangent = np.cross(u, radial)
    s = 1.0 if hand == "right" else -1.0
    beta = math.radians(THUMB_DEG)
    d = math.cos(beta) * radial + s * math.sin(beta) * tangent
    start = (a + b) / 2 + (part_radius + WRIST_M) * radial
    wrist = Capsule(tuple(start), tuple(start + FOREARM_M * d), WRIST_M)
    return fist(a, b, part_radius), wrist


def grip_distribution(mesh, positions: int = POSITIONS, wraps=WRAPS, fallback=None) -> tuple[HeldPart, tuple[Grip, ...]]:
    """The held part (:func:`held_part`) and the grips (see the module docstring), in a fixed
    order: a handle's grips (:func:`handle_grips`, :data:`HANDLE_SHARE` of the weight), then the
    held part's reach, then each of its ``others``; along each, group of places, hand, place (:func:`_grips_along`).
    The held part of a prop with a handle is that of its body without the handle."""
    handle = find_handle(mesh, cut_directions(np.asarray(mesh.vertices, float)))
    if handle is not None:
        part = replace(held_part(without_handle(mesh, handle), fallback), handle=handle)
    else:
        part = held_part(mesh, fallback)
    if handle is None and float(np.max(mesh.extents)) < PINCH_BELOW_M:
        caps = pinch(mesh, np.asarray(part.a), np.asarray(part.b), part.radius_m)
        return part, (Grip("pinched by the fingertips at its thinnest end", "", 0.0, 0.0, tuple(caps)),)
    grips = []
    for n, p in enumerate((part, *part.others)):
        grips += _grips_along(p, positions, wraps, "" if n == 0 else f" of stretch {n + 1}")
    if handle is None:
        return part, tuple(grips)
    held = handle_grips(handle)
    share = HANDLE_SHARE if grips else 1.0
    return part, (
        *(replace(g, weight=share / len(held)) for g in held),
        *(replace(g, weight=(1.0 - share) / len(grips)) for g in grips),
    )


def handle_grips(handle: Handle) -> list[Grip]:
    """A fist round the handle's bar, the fingers through its opening, by either hand, the wrist
    at :data:`HANDLE_WRAPS` away from the body."""
    grips = []
    for hand in ("right", "left"):
        for wrap in HANDLE_WRAPS:
            caps = hand_model(handle.a, handle.b, handle.radius_m, wrap, hand, toward=handle.outward)
            label = f"{hand} hand on the handle, fingers through it, wrist at {wrap:g} deg"
            grips.append(Grip(label, hand, 0.5, float(wrap), caps, on_handle=True))
    return grips


def _grips_along(part: HeldPart, positions: int, wraps, name: str) -> list[Grip]:
    """The grips along one reach (``name`` follows the place in each label): ``positions`` groups
    of palm places or fewer (:data:`STEP`), each group holding every wrap of ``wraps`` once at
    places of its own, so the wraps take turns along ``len(wraps)`` times as many evenly spread
    places: a spot is covered by a share of the grips within one in ``len(wraps)`` of the places
    rather than one in the groups (a grid with every wrap at each place covers a spot near a
    palm's end in all its wraps or in none).  In a group, the right hand in every wrap, then the
    left (the same places)."""
    a, b = part.reach
    L = float(np.linalg.norm(b - a))
    u = (b - a) / max(L, 1e-12)
    palm = min(PALM_M, L)
    k = 1 if L - palm < 0.02 or positions <= 1 else int(min(positions, max(2, math.ceil((L - palm) / (STEP * palm) - 1e-9) + 1)))
    w = len(wraps)
    starts = np.linspace(0.0, L - palm, k * w) if k > 1 else np.zeros(w)
    along = (starts + palm / 2) / max(L, 1e-12)
    grips = []
    for g in range(k):
        places = range(g * w, (g + 1) * w)
        pos = "over the part" if k == 1 else f"at {100 * along[places[0]]:.0f}-{100 * along[places[-1]]:.0f} % of the reach"
        for hand in ("right", "left"):
            for i in places:
                wrap = float(wraps[i % w])
                t = float(starts[i])
                caps = hand_model(a + t * u, a + (t + palm) * u, part.radius_between(t, t + palm), wrap, hand)
                grips.append(Grip(f"{hand} hand {pos}{name}, wrist at {wrap:g} deg", hand, float(along[i]), wrap, caps))
    return grips


def pinned_grip(text: str, grips: tuple[Grip, ...]) -> Grip:
    """``--grip``: ``N`` pins grip N (1-based) of the distribution; ``x0,y0,z0,x1,y1,z1[,r]``
    (prop frame, m) a fist around that segment (:func:`starforge.props.hand.parse_grip`)."""

    t = str(text).strip()
    if t.isdigit():
        n = int(t)
        if not 1 <= n <= len(grips):
            raise StarforgeError(f"--grip {n}: this prop's grips are numbered 1 to {len(grips)} (the run prints them)")
        return grips[n - 1]
    cap = parse_grip(t)
    ends = ", ".join(f"{1000 * float(x):.0f}" for x in t.replace(" ", "").split(",")[:6])
    return Grip(f"pinned: a fist around the segment {ends} mm", "", 0.5, 0.0, (cap,))


def assign_grips(poses: int, grips, rng: np.random.Generator) -> np.ndarray:
    """(poses,) int: the grip each pose is held in, in a random order from ``rng``.

    ``grips`` is their number (each weighs 1) or the grips themselves (each its
    :attr:`Grip.weight`).  Grip g holds ``floor(poses * w_g / sum(w))`` poses, and the spare
    poses go to the largest fractional parts; among equal fractions (equal weights) an order
    drawn from ``rng`` decides, so no grip is favoured for being listed first."""
    w = np.ones(grips) if isinstance(grips, int) else np.array([g.weight for g in grips], float)
    if len(w) <= 1:
        return np.zeros(poses, np.int64)
    exact = poses * w / w.sum()
    counts = np.floor(exact).astype(np.int64)
    order = rng.permutation(len(w))  # breaks ties among equal fractions
    spare = order[np.argsort(-(exact - counts)[order], kind="stable")][: poses - int(counts.sum())]
    counts[spare] += 1
    return rng.permutation(np.repeat(np.arange(len(w), dtype=np.int64), counts))


def grip_arrays(grips) -> tuple[np.ndarray, np.ndarray]:
    """The compiled kernel's input: capsules (h, 8, :func:`starforge.props.hand.capsule_arrays`) grouped by grip, and ``starts`` (g + 1,):
    grip g's capsules are rows ``starts[g]:starts[g + 1]``."""
    if not grips:  # one empty grip: nothing hides anything
        return np.zeros((0, CAPSULE_COLUMNS)), np.zeros(2, np.int64)
    rows = [capsule_arrays(g.capsules) for g in grips]
    counts = [len(r) for r in rows]
    caps = np.concatenate(rows)
    return np.ascontiguousarray(caps, dtype=float), np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)


def under_hand(points: np.ndarray, centres: np.ndarray, grips, share: float = 0.0) -> np.ndarray:
    """(n,) bool: the site (surface ``points`` or ball ``centres``) lies inside the fist (the
    first capsule) of more than ``share`` of the grips, by weight (0: of any)."""
    covered = np.zeros(len(points))
    for g in grips:
        covered += g.weight * (inside_capsules(points, g.capsules[:1]) | inside_capsules(centres, g.capsules[:1]))
    return covered > share * sum(g.weight for g in grips) if grips else np.zeros(len(points), bool)


def grips_summary(part: HeldPart, grips) -> str:
    """One line: how many grips, on what part."""
    if not grips:
        return "no hand"
    what = (
        f"the {part.length_m * 1000:.0f} mm graspable part ({2000 * part.radius_m:.0f} mm across)"
        if part.found else f"its thinnest end ({2000 * part.radius_m:.0f} mm across; no part 20-55 mm across found)"
    )
    a, b = part.reach
    reach = float(np.linalg.norm(b - a))
    where = f"on {what}" if reach <= part.length_m + 1e-3 else f"along {1000 * reach:.0f} mm of the prop: {what} and on past it"
    if part.others:
        where += ", and along " + ", ".join(f"{1000 * o.length_m:.0f} mm ({2000 * o.radius_m:.0f} mm across)" for o in part.others)
        where += f" in another direction (stretch {', '.join(str(n + 2) for n in range(len(part.others)))})"
    hands = sorted({g.hand for g in grips if g.hand})
    h = part.handle
    if h is not None:
        on = sum(g.weight for g in grips if g.on_handle) / sum(g.weight for g in grips)
        where = (
            f"on a handle ({2000 * h.radius_m:.0f} mm thick, its opening {1000 * h.opening_m[0]:.0f} x "
            f"{1000 * h.opening_m[1]:.0f} mm) in {100 * on:.0f} % of the poses, and {where} in the others"
        )
    return f"{len(grips)} grip(s) {where}" + (f", {' and '.join(hands)} hand" if hands else "")


#: a site is under the hand (no marker goes there) when more than this share of the grips' fists
#: cover it: where people hold the prop most; a site fewer grips cover stays, lost in their poses
HELD_SHARE = 0.5

#: the grips' random order over the poses comes from the run's seed + this
GRIP_SEED_OFFSET = 5_000_011
