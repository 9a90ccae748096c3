"""Simulated tracker frames and their tally: bodies at random poses with noise, hidden markers
and ghost points, and the outcome of each body appearance (correct, wrong body, wrong pose,
missed).  The model is :mod:`starforge.tracking.identify`'s (its module docstring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from starforge.tracking.library import Library


@dataclass(frozen=True)
class Scenes:
    """Simulated observations.

    pts : (S, P, 3) float, mm     observed points, NaN = empty slot (slot order shuffled)
    label : (S, P) int            true marker index, -1 ghost, -2 empty
    body : (S,) int               true body of each scene
    frame : (S,) int              frame of each scene
    """

    pts: np.ndarray
    label: np.ndarray
    body: np.ndarray
    frame: np.ndarray


def simulate(
    lib: Library,
    n_frames: int,
    noise_mm: float,
    drop: int,
    ghosts: int,
    rng: np.random.Generator,
    match_mm: float = 1.0,
    drop_exact: bool = False,
    first_frame: int = 0,
    presence: float = 1.0,
) -> Scenes:
    """Frames in which each body of ``lib`` is present with probability ``presence`` and sits at
    a random pose (see :mod:`starforge.tracking.identify`)."""
    from scipy.spatial.transform import Rotation

    B, nmax = lib.n_bodies, lib.n_max
    body = np.tile(np.arange(B), n_frames)
    frame = np.repeat(np.arange(n_frames), B) + first_frame
    if presence < 1.0:
        here = rng.random(len(body)) < presence
        body, frame = body[here], frame[here]
    S = len(body)
    R = Rotation.random(S, random_state=rng).as_matrix()
    t = rng.uniform(-1000.0, 1000.0, size=(S, 3))
    model = lib.points[body]
    X = np.einsum("sij,skj->ski", R, model) + t[:, None, :]
    X = X + rng.normal(0.0, noise_mm, size=X.shape) if noise_mm > 0 else X
    present = np.arange(nmax)[None, :] < lib.counts[body][:, None]
    k = np.full(S, drop) if drop_exact else rng.integers(0, drop + 1, size=S)
    # a body keeps at least 3 markers (a 3-marker body has no hidden-marker case)
    k = np.minimum(k, lib.counts[body] - 3)
    keys = np.where(present, rng.random((S, nmax)), np.inf)
    rank = np.argsort(np.argsort(keys, axis=1), axis=1)
    visible = present & (rank >= k[:, None])
    X[~visible] = np.nan
    label = np.where(visible, np.arange(nmax)[None, :], -2)
    if ghosts > 0:
        centre_b = np.nanmean(lib.points, axis=1)  # (B, 3)
        radius_b = np.nanmax(np.linalg.norm(lib.points - centre_b[:, None], axis=2), axis=1) + match_mm
        c = np.einsum("sij,sj->si", R, centre_b[body]) + t
        u = rng.normal(size=(S, ghosts, 3))
        u /= np.linalg.norm(u, axis=2, keepdims=True)
        r = radius_b[body][:, None] * rng.random((S, ghosts)) ** (1 / 3)
        G = c[:, None, :] + u * r[..., None]
        X = np.concatenate([X, G], axis=1)
        label = np.concatenate([label, np.full((S, ghosts), -1)], axis=1)
    perm = np.argsort(rng.random(label.shape), axis=1)
    X = np.take_along_axis(X, perm[..., None], axis=1)
    label = np.take_along_axis(label, perm, axis=1)
    return Scenes(X, label, body, frame)


@dataclass
class Tally:
    """Counts over simulated frames (B bodies)."""

    n_bodies: int
    confusion: np.ndarray = None  # (B, B): true i reported as j (diagonal: correct)
    flips: np.ndarray = None  # (B,)
    missed: np.ndarray = None  # (B,)
    phantoms: np.ndarray = None  # (B,) label reported on mostly-ghost points
    frames: int = 0
    scenes: int = 0  # body appearances scored (frames x bodies present)
    withheld: int = 0  # chosen matches withheld as ambiguous (:func:`starforge.tracking.identify.unambiguous`)

    def __post_init__(self):
        B = self.n_bodies
        self.confusion = np.zeros((B, B), dtype=np.int64)
        self.flips = np.zeros(B, dtype=np.int64)
        self.missed = np.zeros(B, dtype=np.int64)
        self.phantoms = np.zeros(B, dtype=np.int64)

    @property
    def instances(self) -> int:
        return self.scenes

    @property
    def correct(self) -> int:
        return int(np.trace(self.confusion))

    @property
    def mislabels(self) -> int:
        return int(self.confusion.sum() - np.trace(self.confusion))

    def rates(self) -> dict:
        n = max(self.instances, 1)
        return {
            "identification_rate": self.correct / n,
            "mislabel_rate": (self.mislabels + int(self.flips.sum())) / n,
            "flip_rate": int(self.flips.sum()) / n,
            "wrong_body_rate": self.mislabels / n,
            "missed_rate": int(self.missed.sum()) / n,
            "phantom_rate": int(self.phantoms.sum()) / n,
            "withheld_rate": self.withheld / n,
        }


def score(sc: Scenes, h, chosen: np.ndarray, tally: Tally) -> None:
    """Add the outcome of one batch of scenes to ``tally``: the hypotheses ``h``
    (:class:`starforge.tracking.identify.Hypotheses`) at the rows ``chosen``, scored against
    the scenes' true labels (see :mod:`starforge.tracking.identify`)."""
    S = len(sc.body)
    scene, body, assign, n = h.scene[chosen], h.body[chosen], h.assign[chosen], h.n[chosen]
    lab = np.where(assign >= 0, sc.label[scene[:, None], np.maximum(assign, 0)], -3)
    real = lab >= 0
    n_real = real.sum(axis=1)
    majority = 2 * n_real > n
    right = np.where(real, lab == np.arange(lab.shape[1])[None, :], True).all(axis=1)
    covered = np.zeros(S, dtype=bool)
    # phantoms: reported on mostly ghosts
    np.add.at(tally.phantoms, body[~majority], 1)
    m = majority
    covered[scene[m]] = True
    tb = sc.body[scene[m]]
    rb = body[m]
    ok = right[m]
    same = tb == rb
    np.add.at(tally.confusion, (tb[same & ok], rb[same & ok]), 1)
    np.add.at(tally.flips, tb[same & ~ok], 1)
    np.add.at(tally.confusion, (tb[~same], rb[~same]), 1)
    np.add.at(tally.missed, sc.body[~covered], 1)
    tally.scenes += S
