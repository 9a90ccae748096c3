"""Identification tolerances written into vendor files, from the marker noise and the bodies'
margins.

A tracker's gate must let through the frames of the right body at the lab's noise and keep the
wrong bodies out.  With ``noise_mm`` (sigma per axis) on every marker centre:

* a measured distance between two markers has sigma ``noise * sqrt(2)`` (each end moves
  independently; to first order only the component along the line counts);
* the bone-length tolerance (QTM's ``BoneLengthTolerance``: every distance of the body within
  it) must hold for all C(n, 2) distances of a body: with a per-frame loss budget ``loss``
  (a tenth of what ``keep`` allows, the rest is left to confusions), each distance may fail
  with probability ``loss / C(n, 2)``: ``lower = sigma_d * z`` with ``z`` the two-sided normal
  quantile (a union bound: exact or conservative);
* a wrong body differs from the right one by at least the bodies' one-marker-hidden margin
  ``m`` (:func:`starforge.tracking.library.drop1_margin_mm`) in some distance; measured, it stays
  at least ``m - lower`` away, so any tolerance under ``m - lower`` keeps it out.  The tolerance
  written is the midpoint of ``[lower, m - lower]``, i.e. ``m / 2``; when ``m < 2 lower`` the
  margins cannot serve this noise, the tolerance is ``lower`` (frames are kept) and a note says
  that wrong bodies may pass the gate;
* the residual limit (QTM's ``MaximumResidual``, NDI's maximum marker error) bounds every
  marker's fit residual: a fitted marker's residual is never larger in distribution than its
  noise (3 degrees of freedom), so ``noise * sqrt(chi2_3.isf(loss / n))`` keeps all n markers
  with probability ``1 - loss`` (again a union bound, conservative for the RMS too).

Real vendor files carry wider tolerances (QTM bodies made by QTM: 5-20 mm; NDI's own tool
definitions: 0.75 mm maximum marker error): those are set by hand for robustness, the values
here are the narrowest that keep ``keep`` of the frames at the stated noise.
"""

from __future__ import annotations

import math

import numpy as np

from starforge.spec import non_negative, require

#: the share of frames a file's own gate keeps by default
KEEP = 0.999
#: the part of the allowed loss that the noise gates may use (the rest is left to confusions)
GATE_SHARE = 0.1
#: tolerances stay within these, mm (a tracker needs some slack; over 20 mm no vendor allows)
TOL_RANGE_MM = (0.05, 20.0)


def gate_loss(keep: float = KEEP) -> float:
    """Per-frame probability each noise gate may reject a right body."""
    require(0.5 <= keep < 1.0, f"keep must be in [0.5, 1), got {keep}")
    return (1.0 - keep) * GATE_SHARE


def bone_tolerance_noise_mm(noise_mm: float, n_markers: int, keep: float = KEEP) -> float:
    """The smallest bone-length tolerance that keeps all C(n, 2) measured distances of a body
    within it with probability ``1 - gate_loss(keep)``, mm."""
    from scipy.special import ndtri  # scipy.stats' norm.isf(q) is -ndtri(q); scipy.special loads faster

    non_negative("noise", noise_mm)
    pairs = math.comb(max(int(n_markers), 2), 2)
    z = -float(ndtri(gate_loss(keep) / pairs / 2.0))
    return noise_mm * math.sqrt(2.0) * z


def residual_limit_mm(noise_mm: float, n_markers: int, keep: float = KEEP) -> float:
    """A per-marker fit-residual limit that every one of ``n_markers`` markers stays under with
    probability ``1 - gate_loss(keep)``, mm (also bounds the RMS residual)."""
    from scipy.special import gammainccinv  # chi2.isf(q, 3) is 2 gammainccinv(3/2, q)

    non_negative("noise", noise_mm)
    q = 2.0 * float(gammainccinv(1.5, gate_loss(keep) / max(int(n_markers), 1)))
    return noise_mm * math.sqrt(q)


def export_tolerances(points_list, noise_mm: float = 0.2, keep: float = KEEP) -> dict:
    """The tolerances vendor files get for bodies ``points_list`` (list of (n, 3) mm) at
    ``noise_mm`` (see the module docstring).

    Returns ``noise_mm``, ``keep``, ``margin_mm``, ``bone_length_tolerance_mm``,
    ``maximum_residual_mm`` (QTM), ``max_marker_error_mm`` (NDI), ``bone_from_noise_mm`` (the
    lower bound), ``rule`` (how they were derived) and ``note`` when the margins are too small
    for the noise.
    """
    from starforge.tracking.library import build_library, drop1_margin_mm

    non_negative("noise", noise_mm)
    n = max(len(p) for p in points_list)
    margin = float(drop1_margin_mm(build_library(points_list)))
    lower = bone_tolerance_noise_mm(noise_mm, n, keep)
    lo, hi = TOL_RANGE_MM
    fits = margin >= 2 * lower
    bone = float(np.clip(margin / 2 if fits else lower, lo, hi))
    resid = float(np.clip(residual_limit_mm(noise_mm, n, keep), lo, min(hi, 10.0)))
    out = {
        "noise_mm": float(noise_mm),
        "keep": float(keep),
        "margin_mm": round(margin, 6),
        "bone_from_noise_mm": round(lower, 6),
        "bone_length_tolerance_mm": round(bone, 6),
        "maximum_residual_mm": round(resid, 6),
        "max_marker_error_mm": round(resid, 6),
        "rule": (
            f"bone tolerance: half the bodies' one-marker-hidden margin ({margin:.4g} mm), at least what keeps "
            f"every distance of a {n}-marker body at {noise_mm:g} mm noise ({lower:.4g} mm); residual limit: "
            f"every marker's residual at that noise, each gate losing at most {100 * gate_loss(keep):.3g} % of frames"
        ),
    }
    if not fits:
        out["note"] = (
            f"the bodies' margin {margin:.4g} mm is under twice the noise tolerance {lower:.4g} mm: at "
            f"{noise_mm:g} mm noise a wrong body can pass the bone-length gate; bodies with larger margins "
            f"(or a quieter tracker) avoid it"
        )
    return out


def design_margin_mm(
    noise_mm: float, window_mm: float | None = None, n_markers: int = 4, keep: float = KEEP
) -> float:
    """The key margin a family needs to be safe for a tracker, mm: every face differs from every
    other face, and from itself relabelled, by at least this in some sorted side.

    A tracker gates every distance by its window ``window_mm`` (None: the one starforge writes
    into vendor files, the noise tolerance :func:`bone_tolerance_noise_mm`; a fixed window is
    widened to it, or the right body's frames fail its gate).  A wrong face is ``m`` away and
    measured at least ``m - lower`` away, so it stays out of the gate when ``m >= window +
    lower``; and the tolerance written, ``m / 2`` (:func:`export_tolerances`), must keep the
    right frames, ``m / 2 >= lower``.  Both hold for ``m = 2 max(window, lower)``: the tolerance
    written into the files is then the window itself (at least 3 sigma of a distance, at most
    half the smallest key margin).

    >>> round(design_margin_mm(0.2), 3)  # the default tracker at 0.2 mm: its 1.218 mm window, twice
    2.436
    >>> design_margin_mm(0.2, window_mm=2.0)  # ART's fixed 2 mm window
    4.0
    """
    lower = bone_tolerance_noise_mm(noise_mm, n_markers, keep)
    window = lower if window_mm is None else max(float(window_mm), lower)
    return 2.0 * window
