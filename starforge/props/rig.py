"""Camera rigs and prop poses in the capture volume (metres, world frame, z up).

A camera is a pinhole at ``position`` looking at ``target`` with a horizontal field of view
``fov_deg``; the vertical field of view follows from the resolution's aspect ratio.  Cameras
see in pairs (a marker is reconstructed when both cameras of a pair see it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from starforge.errors import StarforgeError
from starforge.spec import in_range, require


@dataclass(frozen=True)
class Camera:
    """One camera.

    Attributes
    ----------
    position, target : (3,) float, m
    fov_deg : float
        Horizontal field of view, degrees, in (0, 180).
    resolution : (2,) int
        Width and height in pixels (sets the aspect ratio).
    name : str
    """

    position: tuple[float, float, float]
    target: tuple[float, float, float]
    fov_deg: float = 60.0
    resolution: tuple[int, int] = (1280, 1024)
    name: str = ""

    def __post_init__(self):
        in_range(f"camera {self.name or ''} fov_deg".replace("  ", " "), self.fov_deg, 1e-3, 179.0)
        require(
            self.resolution[0] > 0 and self.resolution[1] > 0,
            f"camera resolution must be positive, got {self.resolution}",
        )
        d = np.subtract(self.target, self.position)
        require(float(np.linalg.norm(d)) > 1e-9, f"camera {self.name} target equals its position")

    @property
    def half_tangents(self) -> tuple[float, float]:
        """tan of half the horizontal and vertical fields of view."""
        th = math.tan(math.radians(self.fov_deg) / 2.0)
        return th, th * self.resolution[1] / self.resolution[0]

    def basis(self) -> np.ndarray:
        """(3, 3) rows: right, up, forward unit vectors (world)."""
        f = np.subtract(self.target, self.position).astype(float)
        f /= np.linalg.norm(f)
        up = np.array([0.0, 0.0, 1.0])
        if abs(f @ up) > 0.999:  # looking straight up or down
            up = np.array([0.0, 1.0, 0.0])
        r = np.cross(f, up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        return np.array([r, u, f])


@dataclass(frozen=True)
class Volume:
    """Capture volume: an axis-aligned box, metres."""

    center: tuple[float, float, float] = (0.0, 0.0, 1.0)
    size: tuple[float, float, float] = (2.0, 2.0, 2.0)

    def __post_init__(self):
        require(all(s > 0 for s in self.size), f"volume.size must be > 0 in every axis, got {self.size}")


@dataclass(frozen=True)
class Rig:
    """Cameras, the pairs that triangulate, and the capture volume."""

    cameras: tuple[Camera, ...]
    pairs: tuple[tuple[int, int], ...] | str = "auto"
    volume: Volume = field(default_factory=Volume)
    name: str = "custom"

    def __post_init__(self):
        require(len(self.cameras) >= 2, f"a rig needs at least 2 cameras, got {len(self.cameras)}")
        if isinstance(self.pairs, str):
            require(self.pairs == "auto", f'rig pairs must be a list of [i, j] or "auto", got {self.pairs!r}')
            object.__setattr__(self, "pairs", auto_pairs(self.cameras))
        n = len(self.cameras)
        for i, j in self.pairs:
            require(
                0 <= i < n and 0 <= j < n and i != j,
                f"rig pair [{i}, {j}] must name two different cameras in 0..{n - 1}",
            )
        require(len(self.pairs) >= 1, "a rig needs at least one camera pair")

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "cameras": [
                {
                    "name": c.name,
                    "position": list(c.position),
                    "target": list(c.target),
                    "fov_deg": c.fov_deg,
                    "resolution": list(c.resolution),
                }
                for c in self.cameras
            ],
            "pairs": [list(p) for p in self.pairs],
            "volume": {"center": list(self.volume.center), "size": list(self.volume.size)},
        }


def auto_pairs(cameras) -> tuple[tuple[int, int], ...]:
    """Pair cameras greedily so that each pair's view directions are closest to 90 degrees apart.

    Good triangulation needs sufficiently non-parallel views (the paper, after Olague and Mohr).
    With an odd number of cameras the last one left over joins no pair.
    """
    dirs = np.array([c.basis()[2] for c in cameras])
    n = len(dirs)
    cand = []
    for i in range(n):
        for j in range(i + 1, n):
            ang = math.degrees(math.acos(float(np.clip(dirs[i] @ dirs[j], -1, 1))))
            cand.append((abs(ang - 90.0), i, j))
    cand.sort()
    used: set[int] = set()
    pairs = []
    for _, i, j in cand:
        if i not in used and j not in used:
            pairs.append((i, j))
            used |= {i, j}
    return tuple(pairs)


def load_rig(name_or_path: str = "default") -> Rig:
    """A rig from a shipped template name (``default``) or a TOML file."""
    from starforge.catalog import load_template, values_from
    from starforge.spec import from_mapping

    name, data = load_template("rigs", name_or_path)
    data = dict(data)
    data.setdefault("name", name)
    with values_from(name_or_path):
        return from_mapping(Rig, data, where=f"rig {name}")


@dataclass(frozen=True)
class Poses:
    """Rigid placements of the prop in the capture volume.

    ``world = R @ (p - pivot) + t`` for a point ``p`` in the prop frame.

    Attributes
    ----------
    rotations : (k, 3, 3) float
    translations : (k, 3) float, m
    pivot : (3,) float, m
        Prop point placed at the translation (centre of the prop's bounding box).
    """

    rotations: np.ndarray = field(repr=False)
    translations: np.ndarray = field(repr=False)
    pivot: np.ndarray = field(repr=False)

    def __len__(self) -> int:
        return len(self.rotations)

    def matrices(self) -> np.ndarray:
        """(k, 4, 4) homogeneous prop-to-world transforms."""
        k = len(self)
        out = np.tile(np.eye(4), (k, 1, 1))
        out[:, :3, :3] = self.rotations
        out[:, :3, 3] = self.translations - np.einsum("kij,j->ki", self.rotations, self.pivot)
        return out

    def to_json(self) -> dict:
        return {
            "pivot": (np.round(self.pivot, 12) + 0.0).tolist(),
            "matrices": np.round(self.matrices(), 12).tolist(),
        }


def grid_positions(volume: Volume, resolution: int) -> np.ndarray:
    """(n^3, 3) cell centres of an n x n x n grid over the volume, metres."""
    n = int(in_range("resolution", resolution, 1, 64))
    axes = [c + s * ((np.arange(n) + 0.5) / n - 0.5) for c, s in zip(volume.center, volume.size, strict=True)]
    gx, gy, gz = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])


def orientation_set(count: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """(count, 3, 3) rotations spread over the rotation group: the identity (the prop as modelled,
    upright), then the first ``count - 1`` points of a super-Fibonacci spiral on the unit
    quaternions (Alexa, CVPR 2022), so the set is deterministic and evenly spread for every count
    with no random draws.  ``rng`` is accepted for compatibility and not used."""
    count = int(in_range("orientations", count, 1, 1000))
    rots = [np.eye(3)]
    if count > 1:
        n = count - 1
        psi = 1.533751168755204288  # the real root of psi^4 = psi + 4
        s = np.arange(n) + 0.5
        r, big_r = np.sqrt(s / n), np.sqrt(1.0 - s / n)
        alpha, beta = 2 * np.pi * s / np.sqrt(2.0), 2 * np.pi * s / psi
        w, x, y, z = r * np.sin(alpha), r * np.cos(alpha), big_r * np.sin(beta), big_r * np.cos(beta)
        rots.extend(quaternion_matrices(w, x, y, z))
    return np.array(rots)


def quaternion_matrices(w: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotation matrices of unit quaternions w + xi + yj + zk (normalised here)."""
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def make_poses(volume: Volume, resolution: int, orientations: int, pivot, rng: np.random.Generator) -> Poses:
    """Every grid position times every orientation (position-major order)."""
    pos = grid_positions(volume, resolution)
    rots = orientation_set(orientations, rng)
    R = np.repeat(rots[None], len(pos), axis=0).reshape(-1, 3, 3)
    T = np.repeat(pos, len(rots), axis=0)
    if len(R) == 0:
        raise StarforgeError("no poses")
    return Poses(R, T, np.asarray(pivot, dtype=float))
