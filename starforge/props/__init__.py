"""Prop marker placement (Acevedo et al. 2023, sections 3-5): optimize a marker set on a prop mesh.

Modules: ``mesh`` (load, repair), ``builtin`` (props generated in code), ``sites`` (Poisson-disk
candidate sites, constrained areas), ``seat`` (where a marker's base rests), ``hand`` and
``grips`` (the hand as occluding capsules, where it holds the prop), ``rig`` (cameras, pairs,
poses), ``visibility`` (the sites x poses camera-mask table: compiled tests, embree rays),
``costs`` and ``symmetry`` (eq. 1-5), ``optimizer`` (RJ-MCMC simulated annealing, eq. 6-9),
``tracked`` (the default objective over camera-loss scenarios), ``scenarios`` (the camera
losses), ``spacing`` (how close markers may be; whether any layout can be tracked),
``layout_search`` and ``tracked_optimizer`` (the searches and the choice among their layouts),
``heldout`` (the held-out samples that rank and tune them), ``evaluate`` (the check on fresh
poses), ``spec`` (settings), ``prepare`` (sites, poses and table a placement starts from),
``placement`` (the pipeline; :func:`starforge.props.placement.run_placement`), ``result``
(:class:`~starforge.props.result.PlacementResult`), ``score`` (scoring a given layout),
``files`` (placement.json and the files beside it, :func:`load_placement`), ``guide``
(landmarks, pads).
Importing this package is light; heavy libraries load inside the functions that use them.
"""

from __future__ import annotations

__all__ = ["load_placement"]


def load_placement(path):
    """Read a ``placement.json`` (or the folder holding one); see :func:`starforge.props.files.load_placement`."""
    from starforge.props.files import load_placement as _load

    return _load(path)
