"""Prop meshes: load any format trimesh reads, convert units, repair, orient normals outward.

Everything here works in metres.  The result is a :class:`PropMesh`: the repaired mesh's
vertices and faces (its ``trimesh.Trimesh`` built on first use), the original face index of
every face (for per-face masks) and a list of plain-language notes saying what was repaired.
"""

from __future__ import annotations

import gc
import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.props.scan import noisy, smooth_scan
from starforge.props.solids import union_solids

UNITS_TO_M = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".glb", ".gltf", ".off")


@dataclass(frozen=True, eq=False)
class PropMesh:
    """A repaired prop mesh in metres.

    The mesh is kept as arrays; :attr:`mesh`, the ``trimesh.Trimesh`` of them, is built on first
    use, so that work that needs only the arrays (a placement read back from the cache up to its
    layout) does not import trimesh.

    Attributes
    ----------
    name : str
        Built-in name or file stem.
    source : str
        ``builtin`` or the file path as given.
    units : str
        Units of the source file (``m``, ``cm`` or ``mm``); the mesh itself is in metres.
    vertices : (v, 3) float
        Vertices, m.
    faces : (f, 3) int
        Triangles (indices into ``vertices``), wound with their normals outward where that can
        be decided.
    face_origin : (f,) int
        Index of each face in the file as loaded; -1 for faces added by repair (filled holes).
    notes : tuple of str
        What the repair did, one short line per action.
    source_faces : int
        Number of faces in the source as loaded (the length a per-face mask must have).
    """

    name: str
    source: str
    units: str
    vertices: np.ndarray = field(repr=False)
    faces: np.ndarray = field(repr=False)
    face_origin: np.ndarray = field(repr=False)
    notes: tuple[str, ...] = ()
    source_faces: int = 0
    timings: dict = field(default_factory=dict)

    @classmethod
    def of(cls, mesh, name: str, source: str, units: str, face_origin, notes=(), source_faces: int = 0, timings=None) -> PropMesh:
        """The PropMesh of a ``trimesh.Trimesh`` (m), kept as its :attr:`mesh` with what trimesh
        has computed of it."""
        out = cls(
            name, source, units, np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64),
            np.asarray(face_origin), tuple(notes), int(source_faces), dict(timings or {}),
        )  # fmt: skip
        out.__dict__["mesh"] = mesh
        return out

    @cached_property
    def mesh(self):
        """The ``trimesh.Trimesh`` of :attr:`vertices` and :attr:`faces` (built on first use)."""
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, process=False)

    @cached_property
    def bounds_m(self) -> np.ndarray:
        """(2, 3) float, m: :func:`face_bounds` of the prop."""
        return face_bounds(self.vertices, self.faces)

    @cached_property
    def watertight(self) -> bool:
        """Every edge (a pair of vertex indices) is shared by exactly two faces: trimesh's
        ``is_watertight``, from the arrays (true of no faces, as there); trimesh's own where the
        mesh is built, which its repair has already computed."""
        if "mesh" in self.__dict__:
            return bool(self.mesh.is_watertight)
        f = np.asarray(self.faces, dtype=np.int64)
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _, counts = np.unique(e[:, 0] * (len(self.vertices) + 1) + e[:, 1], return_counts=True)
        return bool(np.all(counts == 2))

    @property
    def extents_m(self) -> np.ndarray:
        """(3,) float, m: axis-aligned size of the prop."""
        return np.ptp(self.bounds_m, axis=0)

    def __getstate__(self) -> dict:
        """The arrays only: a pickled prop (sent to a worker, kept in the cache) builds its
        ``trimesh.Trimesh`` again where it is used."""
        return {k: v for k, v in self.__dict__.items() if k not in ("mesh",)}


def face_bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(2, 3) float: the corners of the axis-aligned box round the vertices the faces use (a
    vertex no face uses is left out, as trimesh's ``bounds`` leaves it out); zeros for no faces."""
    used = np.zeros(len(vertices), dtype=bool)
    used[np.asarray(faces).ravel()] = True
    v = np.asarray(vertices, dtype=float)[used]
    return np.array([v.min(axis=0), v.max(axis=0)]) if len(v) else np.zeros((2, 3))


#: vertices whose coordinates agree to this many decimals (of a metre) are one vertex: trimesh's
#: ``tol.merge`` (1e-8), so that the merge is trimesh's ``merge_vertices``
MERGE_DIGITS = 8


def merge_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, faces)`` with vertices that round to the same :data:`MERGE_DIGITS` decimals
    merged into the first of them, and those no face uses dropped: the arrays trimesh's
    ``Trimesh.merge_vertices`` leaves (a mesh without normals or texture), in the same order, bit
    for bit.  Rows are grouped by one sort of their rounded coordinates (x and y packed into one
    integer where they fit) rather than trimesh's sort of 24-byte rows, a third of its time on
    an STL's three unshared vertices per face."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    ref = np.flatnonzero(used)
    if not len(ref):
        return v[:0].copy(), f.copy()
    key = np.round(v[ref] * 10.0**MERGE_DIGITS).astype(np.int64)
    lo = key.min(axis=0)
    bits = [int(x).bit_length() for x in key.max(axis=0) - lo]
    if bits[0] + bits[1] <= 62:
        order = np.lexsort((key[:, 2], ((key[:, 0] - lo[0]) << bits[1]) | (key[:, 1] - lo[1])))
    else:
        order = np.lexsort((key[:, 2], key[:, 1], key[:, 0]))
    ranked = key[order]
    starts = np.ones(len(ranked), dtype=bool)
    np.any(ranked[1:] != ranked[:-1], axis=1, out=starts[1:])
    first = order[starts]  # lexsort is stable: each group's first occurrence
    by_first = np.argsort(first, kind="stable")
    renumber = np.empty(len(first), dtype=np.int64)
    renumber[by_first] = np.arange(len(first))
    inverse = np.zeros(len(v), dtype=np.int64)
    inverse[ref[order]] = renumber[np.cumsum(starts) - 1]
    return v[ref[first[by_first]]], inverse[f]


def units_hint(size_m: float, units: str, lo_m: float, hi_m: float) -> str:
    """Advice naming ``--units`` for a prop ``size_m`` across when read as ``units``: the units
    that make it between ``lo_m`` and ``hi_m``, the one nearest a hand-held size (0.3 m) first."""
    here = UNITS_TO_M.get(units, 1.0)
    fits = [u for u, f in UNITS_TO_M.items() if u != units and lo_m <= size_m / here * f <= hi_m]
    fits.sort(key=lambda u: abs(math.log(size_m / here * UNITS_TO_M[u] / 0.3)))
    if not fits:
        return f"no --units ({', '.join(UNITS_TO_M)}) makes it a prop's size: check the file's scale"
    size = size_m / here * UNITS_TO_M[fits[0]]
    return f"pass --units {fits[0]} (it is then {size:.3g} m across)"


def units_scale(units: str) -> float:
    """Metres per file unit; StarforgeError naming ``units`` when unknown."""
    if units not in UNITS_TO_M:
        raise StarforgeError(f"units must be one of {', '.join(UNITS_TO_M)}, got {units!r}")
    return UNITS_TO_M[units]


def load_mesh_file(path: str | Path, units: str = "m", what: str = "prop mesh"):
    """Read a mesh file (STL, OBJ, PLY, GLB, OFF, ...) into one ``trimesh.Trimesh`` in metres, unrepaired.

    Scenes (GLB, multi-object OBJ) are flattened with their transforms applied.
    Raises StarforgeError for a missing, unreadable or empty file, or one that is not a regular
    file (a device, a FIFO); ``what`` names the file in the message (``"--forbid-mesh file"``).
    """
    import trimesh

    from starforge.io import check_input_file

    scale = units_scale(units)
    path = check_input_file(Path(path), what, "mesh")
    from starforge.runtime.budget import require_memory

    # a mesh in memory takes about 10-20 x its file size (vertices, faces, adjacency, repair)
    require_memory(
        path.stat().st_size * 20.0, f"the {what} {path} ({path.stat().st_size / 1e6:.0f} MB)", "simplify the mesh first"
    )
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise StarforgeError(f"cannot read {what} {path}: {exc.__class__.__name__}: {exc}") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise StarforgeError(f"{what} {path} holds no triangles; give a mesh (STL, OBJ, PLY, GLB, OFF) with faces")
    vertices = np.asarray(loaded.vertices, dtype=float) * scale
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if not np.all(np.isfinite(vertices)):
        raise StarforgeError(
            f"{what} {path} has non-finite vertex coordinates (nan or inf); fix the mesh in its editor and export it again"
        )
    size = float(np.ptp(vertices, axis=0).max()) if len(vertices) else 0.0
    if size > MAX_SIZE_M:  # beyond this, float arithmetic in the repair overflows
        raise StarforgeError(
            f"{what} {path} is {size:,.4g} m across read as {units}: no prop is that large "
            f"(at most {MAX_SIZE_M:g} m); {units_hint(size, units, 0.01, MAX_SIZE_M)}"
        )
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


#: largest prop extent accepted, m (a capture volume is tens of metres)
MAX_SIZE_M = 1000.0


def repair_mesh(mesh, union_shells: bool = True, smooth: bool = True):
    """Repair a raw mesh for placement; return ``(mesh, face_origin, notes)``.

    Steps (each reported in ``notes`` when it changed something): merge duplicate vertices,
    drop degenerate and duplicate faces, make winding consistent and normals outward per
    connected shell, fill small holes, smooth a scan's noise (:mod:`starforge.props.scan`), and
    merge overlapping watertight shells into one surface with a boolean union (manifold3d) so
    that no candidate site lies buried inside another shell.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Raw mesh, metres.
    union_shells : bool
        Merge two or more watertight shells with a boolean union.
    smooth : bool
        Smooth a scan's noise away (:mod:`starforge.props.scan`) when the mesh carries enough
        of it to tilt its faces (:func:`starforge.props.scan.noisy`).

    Returns
    -------
    mesh : trimesh.Trimesh
    face_origin : (f,) int
        Input face index of every output face, -1 for faces the repair created.
    notes : list of str
    """
    import trimesh

    notes: list[str] = []
    nv = len(mesh.vertices)
    m = trimesh.Trimesh(*merge_vertices(mesh.vertices, mesh.faces), process=False)
    origin = np.arange(len(m.faces))
    if len(m.vertices) < nv:
        notes.append(f"merged {nv - len(m.vertices)} duplicate vertices")
    keep = m.nondegenerate_faces(height=1e-12)
    unique = np.zeros(len(m.faces), dtype=bool)
    unique[m.unique_faces()] = True
    keep &= unique
    if not keep.all():
        notes.append(f"removed {int((~keep).sum())} degenerate or duplicate faces")
        m.update_faces(keep)
        origin = origin[keep]
    m.remove_unreferenced_vertices()
    if len(m.faces) == 0:
        raise StarforgeError("prop mesh has no usable faces after removing degenerate ones")

    # consistent winding and outward normals, shell by shell
    before = m.faces.copy()
    trimesh.repair.fix_winding(m)
    n_shells = len(_shells(m))
    _fix_inversion(m, n_shells)
    flipped = int(np.any(m.faces != before, axis=1).sum())
    if flipped:
        notes.append(f"flipped {flipped} faces so normals point outward")

    if not m.is_watertight:
        n_shells = None  # filling holes and turning shells change the faces: counted again below
        nf = len(m.faces)
        trimesh.repair.fill_holes(m)
        added = len(m.faces) - nf
        if added > 0:
            origin = np.concatenate([origin, -np.ones(added, dtype=origin.dtype)])
            notes.append(f"filled holes with {added} faces")

    if not m.is_watertight:
        n_open = _orient_open_shells(m)
        if n_open:
            notes.append(
                f"turned {n_open} open shell{'s' if n_open > 1 else ''} inside out (normals faced inward)"
            )

    if smooth:
        noise, radius = noisy(m.vertices, m.faces)
        if noise:
            m.vertices = smooth_scan(m.vertices, m.faces, radius=radius)
            notes.append(
                f"smoothed scanner noise of {1000 * noise:.3f} mm RMS (every vertex onto the surface fitted "
                f"within {1000 * radius:.1f} mm round it)"
            )

    if n_shells is None:
        n_shells = len(_shells(m))
    shells = m.split(only_watertight=False) if n_shells > 1 else [m]
    if len(shells) > 1:
        notes.append(f"{len(shells)} separate shells")
    tight = [s for s in shells if s.is_watertight and s.is_volume] if len(shells) > 1 else []
    if union_shells and len(tight) >= 2 and _any_overlap(tight):
        merged = union_solids(tight)
        if merged is not None:
            loose = [s for s in shells if not (s.is_watertight and s.is_volume)]
            parts = [merged, *loose]
            m = trimesh.util.concatenate(parts) if len(parts) > 1 else merged
            # faces from a union have no single source face: keep the mask by nearest source face
            origin = _nearest_origin(mesh, origin, m)
            notes.append(
                f"united {len(tight)} watertight shells (boolean union) so no surface is buried in another"
            )
    if len(m.faces) == 0 or m.area <= 0:
        raise StarforgeError("prop mesh has no usable surface after repair")
    return m, origin, notes


def _shells(m) -> list:
    """The face indices of each connected shell of ``m`` (a lone face is a shell of its own)."""
    from trimesh.graph import connected_components

    return connected_components(m.face_adjacency, nodes=np.arange(len(m.faces)), min_len=1)


def _fix_inversion(m, n_shells: int) -> None:
    """Turn every closed, consistently wound shell of ``m`` with a negative volume inside out
    (trimesh's ``fix_inversion(multibody=True)``; a mesh of ``n_shells == 1`` is checked whole,
    without splitting it into submeshes first, which dominates on a fine mesh)."""
    import trimesh

    if n_shells > 1:
        trimesh.repair.fix_inversion(m, multibody=True)
        return
    if len(m.faces) < 4 or not (m.is_watertight and m.is_winding_consistent):
        return
    if signed_volume(m) < 0.0:
        m.faces = np.fliplr(m.faces)


def signed_volume(m) -> float:
    """The volume a closed mesh's faces enclose, m^3: positive when they wind outward (the sum of
    the tetrahedra from the vertices' mean to every face)."""
    tri = np.asarray(m.triangles, float) - np.asarray(m.vertices, float).mean(axis=0)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return float(np.einsum("ij,ij->", tri[:, 0], cross)) / 6.0


def _orient_open_shells(m, samples: int = 64) -> int:
    """Flip open (non-watertight) shells whose normals mostly point inward; return how many.

    Volume tells nothing for an open shell, so rays are cast from face centres: along an
    outward normal a ray mostly escapes, along an inward one it mostly hits the prop again.
    A shell is flipped only when clearly more rays hit along its normals than against them.
    """
    from trimesh.graph import connected_components

    groups = connected_components(m.face_adjacency, nodes=np.arange(len(m.faces)), min_len=1)
    edges_sorted = np.sort(m.edges, axis=1)
    flipped = 0
    new_faces = np.array(m.faces)
    for faces in groups:
        faces = np.sort(np.asarray(faces))
        e = edges_sorted.reshape(-1, 3, 2)[faces].reshape(-1, 2)
        _, counts = np.unique(e, axis=0, return_counts=True)
        if np.all(counts == 2):
            continue  # closed shell: fix_inversion already handled it
        pick = faces[np.linspace(0, len(faces) - 1, min(samples, len(faces))).astype(int)]
        area = m.area_faces[pick]
        c = m.triangles_center[pick]
        n = m.face_normals[pick]
        eps = 1e-6 * float(m.scale)
        out_hit = m.ray.intersects_any(c + eps * n, n)
        in_hit = m.ray.intersects_any(c - eps * n, -n)
        w_out, w_in = float(area[out_hit].sum()), float(area[in_hit].sum())
        if w_out > 1.5 * w_in and w_out > 0.25 * float(area.sum()):
            new_faces[faces] = new_faces[faces][:, ::-1]
            flipped += 1
    if flipped:
        m.faces = new_faces
    return flipped


def _any_overlap(shells) -> bool:
    boxes = np.array([s.bounds for s in shells])
    lo, hi = boxes[:, 0], boxes[:, 1]
    for i in range(len(shells)):
        for j in range(i + 1, len(shells)):
            if np.all(lo[i] <= hi[j]) and np.all(lo[j] <= hi[i]):
                return True
    return False


def _nearest_origin(raw, origin, new):
    """Source face index for each face of ``new``: the nearest face of the repaired-before mesh."""
    from scipy.spatial import cKDTree

    origin = np.asarray(origin)
    known = origin[origin >= 0]
    if len(known) == 0:
        return -np.ones(len(new.faces), dtype=np.int64)
    _, idx = cKDTree(raw.triangles_center[known]).query(new.triangles_center)
    return known[idx]


def load_prop(prop: str, units: str = "m", repair: bool = True, smooth: bool = True) -> PropMesh:
    """A built-in prop name (``hammer``, or ``builtin:hammer``) or a mesh file path -> repaired
    :class:`PropMesh` in metres.  A bare built-in name that is also a file here reads the file
    (``builtin:NAME`` names the built-in); a folder of that name does not hide the built-in.
    ``smooth``: the repair smooths a scan's noise (:func:`repair_mesh`).  ``timings`` holds the
    seconds spent loading and repairing."""
    import time

    from starforge.props.builtin import BUILTIN, builtin_arrays

    t0 = time.perf_counter()
    units_scale(units)  # validate even for built-ins (which are in metres)
    text = str(prop)
    if text.startswith("builtin:"):
        text = text.removeprefix("builtin:")
        if text not in BUILTIN:
            raise StarforgeError(f"unknown built-in prop {text!r}; built-ins: {', '.join(BUILTIN)}")
    elif text in BUILTIN and Path(text).is_file():
        text = str(prop) if "/" in str(prop) else f"./{text}"  # a file of that name wins; said so
    if text in BUILTIN:
        vertices, faces = builtin_arrays(text)
        n = len(faces)
        return PropMesh(text, "builtin", "m", vertices, faces, np.arange(n), (), n, {"load_s": round(time.perf_counter() - t0, 4)})
    path = Path(text)
    if not path.exists() and path.suffix.lower() not in MESH_SUFFIXES:
        raise StarforgeError(
            f"unknown prop {text!r}: not a file and not a built-in; built-ins: {', '.join(BUILTIN)}"
        )
    if not repair:
        raw = _loaded(path, units)
        timings = {"load_s": round(time.perf_counter() - t0, 4)}
        return PropMesh.of(raw, path.stem, text, units, np.arange(len(raw.faces)), (), len(raw.faces), timings)
    return _repaired(path, text, units, t0, smooth)


def _loaded(path: Path, units: str):
    """The mesh file read (:func:`load_mesh_file`), refused past :data:`MAX_FACES`."""
    raw = load_mesh_file(path, units)
    if len(raw.faces) > MAX_FACES:
        raise StarforgeError(f"prop mesh {path} has {len(raw.faces):,} faces; at most {MAX_FACES:,} (simplify it first)")
    return raw


def _repaired(path: Path, text: str, units: str, t0: float, smooth: bool = True) -> PropMesh:
    """The mesh file read and repaired, kept in the cache folder
    (:func:`starforge.runtime.stored.stored`) by the file's bytes (a BLAKE2b digest), its
    suffix, ``units``, ``smooth`` and the versions of the libraries that read and repair it: a later run on
    the same file reads the repaired arrays back without reading the file with trimesh.  A file
    larger than :data:`KEEP_BYTES` is read and repaired on every run."""
    import hashlib
    import time

    from starforge.io import check_input_file
    from starforge.runtime.stored import content_key, stored

    path = check_input_file(path, "prop mesh", "mesh")
    timings: dict = {}
    made: dict = {}

    def work():
        raw = _loaded(path, units)
        t1 = time.perf_counter()
        timings["load_s"] = round(t1 - t0, 4)
        try:
            mesh, origin, notes = repair_mesh(raw, smooth=smooth)
        except StarforgeError as exc:
            raise StarforgeError(f"{path}: {exc}") from None
        n_raw = len(raw.faces)
        if n_raw > COLLECT_FACES:
            # the loader's and the repair's meshes hold reference cycles (a mesh and its caches),
            # hundreds of MB on a fine mesh, which a command running with the collector paused keeps
            del raw
            gc.collect()
        timings["repair_s"] = round(time.perf_counter() - t1, 4)
        made["mesh"] = mesh
        # kept as 32-bit indices (fewer than 2**31 of anything under MAX_FACES): half the bytes
        return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32), np.asarray(origin, np.int32), tuple(notes), n_raw

    if path.stat().st_size > KEEP_BYTES:  # a mesh this large is read again rather than kept
        vertices, faces, origin, notes, n_raw = work()
    else:
        with open(path, "rb") as fh:
            digest = hashlib.file_digest(fh, "blake2b").hexdigest()
        libraries = ("numpy", "scipy", "trimesh", "manifold3d", "networkx")
        key = content_key("repaired", digest, path.suffix.lower(), units, smooth, libraries=libraries)
        (vertices, faces, origin, notes, n_raw), _ = stored("repaired", key, work)
    origin = origin.astype(np.int64)
    if "mesh" in made:  # computed here: the mesh, with what trimesh computed of it, is kept
        return PropMesh.of(made["mesh"], path.stem, text, units, origin, notes, n_raw, timings)
    timings["load_s"] = round(time.perf_counter() - t0, 4)
    return PropMesh(path.stem, text, units, vertices, faces.astype(np.int64), origin, notes, n_raw, timings)


#: a mesh file up to this size (bytes; a binary STL of a million faces) is kept repaired in the
#: cache folder (about 30 MB at that size)
KEEP_BYTES = 50_000_000


#: a mesh file with more faces is followed by a garbage collection once it is repaired
COLLECT_FACES = 100_000


#: faces a prop mesh may have (a 5 M-face mesh takes about 2 GB while it is repaired)
MAX_FACES = 5_000_000
