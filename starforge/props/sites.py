"""Candidate marker sites: Poisson-disk samples of the prop surface, and constrained areas.

Sites are points on the surface (metres, prop frame) with the outward unit normal of the face
they lie on.  Sampling is dart throwing over a dense uniform sample (``trimesh.sample``): the
candidates are visited in random order and one is kept when no kept one lies closer than the
disk radius; the radius is bisected so that at least ``count`` survive, then the first
``count`` kept (in visiting order) are returned, which keeps the minimum spacing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.io import check_input_file
from starforge.runtime.kernels import numba
from starforge.spec import in_range, positive


@dataclass(frozen=True)
class Sites:
    """Candidate marker sites.

    Attributes
    ----------
    points : (s, 3) float, m
        Positions on the surface, prop frame.
    normals : (s, 3) float
        Outward unit normals.
    faces : (s,) int
        Face of the repaired mesh each site lies on.
    radius_m : float
        Poisson-disk radius: no two sites are closer than this.
    """

    points: np.ndarray = field(repr=False)
    normals: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    radius_m: float = 0.0

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, keep: np.ndarray) -> Sites:
        """The sites where the boolean mask ``keep`` is true."""
        return Sites(self.points[keep], self.normals[keep], self.faces[keep], self.radius_m)


def _dart_throw(points: np.ndarray, radius: float, limit: int, tree=None) -> np.ndarray:
    """Indices kept by greedy dart throwing over ``points`` (already in random order);
    ``tree``: a ``cKDTree`` of ``points`` when the caller has one."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points) if tree is None else tree
    pairs = tree.query_pairs(radius, output_type="ndarray")
    n = len(points)
    if len(pairs) == 0:
        return np.arange(min(n, limit))
    both = np.concatenate([pairs, pairs[:, ::-1]])
    order = np.argsort(both[:, 0], kind="stable")
    both = both[order]
    starts = np.searchsorted(both[:, 0], np.arange(n + 1))
    return _greedy_keep(starts, np.ascontiguousarray(both[:, 1]), limit)


@numba.njit(cache=True, nogil=True)
def _greedy_keep(starts, nbr, limit):
    """Visit candidates 0, 1, ... in order; keep one unless a kept one's neighbour list
    (``nbr[starts[i]:starts[i + 1]]``, CSR) blocked it; stop at ``limit`` kept."""
    n = starts.shape[0] - 1
    blocked = np.zeros(n, dtype=np.bool_)
    kept = np.empty(min(n, limit), dtype=np.int64)
    k = 0
    for i in range(n):
        if blocked[i]:
            continue
        kept[k] = i
        k += 1
        if k >= limit:
            break
        for j in range(starts[i], starts[i + 1]):
            blocked[nbr[j]] = True
    return kept[:k]


def sample_sites(mesh, count: int, rng: np.random.Generator, oversample: int = 6) -> Sites:
    """Poisson-disk sample ``count`` candidate sites on ``mesh`` (metres).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Prop surface, normals outward.
    count : int
        Number of sites wanted (the paper: 1000), 1 to 100000.
    rng : numpy.random.Generator
        Source of randomness (same seed, same sites).
    oversample : int
        Dense uniform candidates per wanted site.

    Returns
    -------
    Sites
        Exactly ``count`` sites (fewer only for a degenerate surface).
    """
    import trimesh

    count = int(in_range("sites", count, 1, 100000))
    n_dense = max(count * oversample, 64)
    pts, face_idx = trimesh.sample.sample_surface(mesh, n_dense, seed=rng)
    pts = np.asarray(pts, dtype=float)
    face_idx = np.asarray(face_idx, dtype=np.int64)
    area = float(mesh.area)
    # a hexagonal packing with spacing r takes (sqrt(3)/2) r^2 per point (an upper bound on r);
    # saturated random dart throwing takes about pi r^2 / (4 * 0.547) = 1.44 r^2 per point
    hi = np.sqrt(area / (count * np.sqrt(3) / 2.0))
    lo = 0.0
    best = np.arange(min(count, n_dense))
    first = 0.9 * np.sqrt(area / (count * 1.44))
    from scipy.spatial import cKDTree

    tree = cKDTree(pts)  # one tree for every radius tried
    kept = _dart_throw(pts, first, count, tree)
    if len(kept) >= count:
        lo, best = first, kept
    else:
        hi = first
    for _ in range(9):
        mid = 0.5 * (lo + hi)
        kept = _dart_throw(pts, mid, count, tree)
        if len(kept) >= count:
            lo, best = mid, kept
        else:
            hi = mid
    normals = np.asarray(mesh.face_normals[face_idx[best]], dtype=float)
    return Sites(pts[best], normals, face_idx[best], float(lo))


@dataclass(frozen=True)
class BoxRegion:
    """Axis-aligned box in the prop frame, metres."""

    min: tuple[float, float, float]
    max: tuple[float, float, float]

    def __post_init__(self):
        if any(a > b for a, b in zip(self.min, self.max, strict=True)):
            raise StarforgeError(f"constraint box min must be <= max, got min={self.min} max={self.max}")


@dataclass(frozen=True)
class SphereRegion:
    """Ball in the prop frame, metres."""

    center: tuple[float, float, float]
    radius: float

    def __post_init__(self):
        positive("constraint sphere radius", self.radius)


@dataclass(frozen=True)
class Constraints:
    """Constrained areas where markers may not go (the paper's Fig. 4).

    Attributes
    ----------
    boxes, spheres : tuples of regions, prop frame, metres
    mesh : str
        Path of a second mesh: sites inside it, or within ``mesh_margin_m`` of its surface, are removed.
    mesh_units : str
        Units of that mesh file.
    mesh_margin_m : float
        Distance from the constraint mesh's surface that still counts as inside, m.
    mask : str
        Path of a per-face mask: one value per face of the prop file as loaded
        (text, comma or whitespace separated, or ``.npy``); non-zero means forbidden.
    """

    boxes: tuple[BoxRegion, ...] = ()
    spheres: tuple[SphereRegion, ...] = ()
    mesh: str = ""
    mesh_units: str = "m"
    mesh_margin_m: float = 0.001
    mask: str = ""

    def __post_init__(self):
        if self.mesh_margin_m < 0:
            raise StarforgeError(f"constraints.mesh_margin_m must be >= 0, got {self.mesh_margin_m}")

    @property
    def empty(self) -> bool:
        return not (self.boxes or self.spheres or self.mesh or self.mask)


#: what a face mask file holds, said with every refusal of one
_MASK_FORM = "give --mask a UTF-8 text file of one 0 or 1 per face of the prop (1: no marker), or a .npy array"


def read_face_mask(path: str | Path, n_faces: int) -> np.ndarray:
    """(n_faces,) bool from a mask file; StarforgeError when missing, corrupt or of the wrong length."""
    path = check_input_file(Path(path), "face mask", "mask")
    try:
        if path.suffix.lower() == ".npy":
            values = np.load(path, allow_pickle=False).ravel()
        else:
            text = path.read_text(encoding="utf-8").replace(",", " ")
            values = np.array([float(v) for v in text.split()])
    except (ValueError, OSError, UnicodeDecodeError) as exc:
        raise StarforgeError(f"face mask {path} is not readable ({exc}); {_MASK_FORM}") from None
    if len(values) != n_faces:
        raise StarforgeError(f"face mask {path} has {len(values):,} values, the prop has {n_faces:,} faces; {_MASK_FORM}")
    if not np.all(np.isfinite(values)):
        raise StarforgeError(f"face mask {path} has a value that is not a finite number; {_MASK_FORM}")
    return np.asarray(values != 0, dtype=bool)


def forbidden_sites(
    sites: Sites,
    constraints: Constraints,
    face_origin: np.ndarray | None = None,
    n_source_faces: int | None = None,
) -> np.ndarray:
    """(s,) bool: sites inside any constrained area.

    Parameters
    ----------
    sites : Sites
    constraints : Constraints
    face_origin : (f,) int, optional
        Source face of each repaired face (:class:`PropMesh.face_origin`), for the per-face mask.
    n_source_faces : int, optional
        Number of faces in the source file (length the mask must have).
    """
    p = sites.points
    bad = np.zeros(len(p), dtype=bool)
    for b in constraints.boxes:
        bad |= np.all((p >= np.asarray(b.min)) & (p <= np.asarray(b.max)), axis=1)
    for s in constraints.spheres:
        bad |= np.linalg.norm(p - np.asarray(s.center), axis=1) <= s.radius
    if constraints.mesh:
        from starforge.props.mesh import load_mesh_file

        other = load_mesh_file(constraints.mesh, constraints.mesh_units, what="constraint mesh (--forbid-mesh)")
        other.merge_vertices()
        if other.is_watertight and other.volume < 0:
            other.invert()
        _, dist, _ = other.nearest.on_surface(p)
        near = dist <= constraints.mesh_margin_m
        inside = other.contains(p) if other.is_watertight else np.zeros(len(p), dtype=bool)
        bad |= near | inside
    if constraints.mask:
        if face_origin is None or n_source_faces is None:
            raise StarforgeError("a per-face mask needs the prop's source faces")
        mask = read_face_mask(constraints.mask, n_source_faces)
        src = face_origin[sites.faces]
        bad |= (src >= 0) & mask[np.clip(src, 0, None)]
    return bad
