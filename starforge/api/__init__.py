"""The few calls a notebook needs; the command line calls the same ones.

Each call takes plain values (names of shipped templates, paths, numbers in the units their
names give) and returns a typed result: a :class:`~starforge.stars.model.Family`, a
:class:`~starforge.props.result.PlacementResult`, an :class:`ExportResult`, a
:class:`CheckResult`.  Files are written only by the ``write_*``, ``export_*`` and ``run_*``
calls, into a staging folder published at once (nothing half-written is left behind), and
never over existing files without ``force=True``.  Each ``run_*`` call is one command
(``starforge stars``, ``export``, ``check``, ``sweep``, ``place``, ``place-batch``) with its options as keywords, and each
``describe_*`` call says its result in the words the command prints.

>>> import starforge.api as sf
>>> plan = sf.plan_family(box_mm=(14, 10, 30), delta_mm=2.0)
>>> family = sf.make_family(plan)
>>> len(family) > 0 and family.spec.box_mm == (14.0, 10.0, 30.0)
True
"""

from __future__ import annotations

from starforge.api.bodies import (
    ExportResult,
    describe_export,
    export_bodies,
    load_printable,
    run_export,
    write_tracker_files,
)
from starforge.api.check import CheckResult, CheckRun, CheckSummary, check, describe_check, run_check
from starforge.api.place import (
    PlacePlan,
    PlaceRun,
    ScoreResult,
    describe_placement,
    describe_score,
    distinct_tolerance_mm,
    distinct_tolerances_mm,
    place_markers,
    placement_files,
    plan_placement,
    run_place,
    score_markers,
    write_placement,
)
from starforge.api.place_batch import (
    PlaceBatchPlan,
    PlaceBatchRun,
    describe_place_batch,
    plan_place_batch,
    run_place_batch,
)
from starforge.api.stars import (
    FAMILY_FILES,
    StarPlan,
    StarsRun,
    describe_family,
    make_family,
    plan_family,
    run_stars,
    tolerance_warning,
    write_family,
)
from starforge.api.sweep import SweepPlan, SweepRun, describe_sweep, plan_sweep, run_sweep

__all__ = [
    "FAMILY_FILES",
    "StarPlan",
    "StarsRun",
    "ExportResult",
    "CheckResult",
    "CheckRun",
    "CheckSummary",
    "plan_family",
    "make_family",
    "write_family",
    "run_stars",
    "describe_family",
    "tolerance_warning",
    "export_bodies",
    "load_printable",
    "write_tracker_files",
    "run_export",
    "describe_export",
    "distinct_tolerance_mm",
    "distinct_tolerances_mm",
    "PlacePlan",
    "PlaceRun",
    "ScoreResult",
    "plan_placement",
    "place_markers",
    "placement_files",
    "write_placement",
    "run_place",
    "describe_placement",
    "score_markers",
    "describe_score",
    "PlaceBatchPlan",
    "PlaceBatchRun",
    "plan_place_batch",
    "run_place_batch",
    "describe_place_batch",
    "check",
    "run_check",
    "describe_check",
    "SweepPlan",
    "SweepRun",
    "plan_sweep",
    "run_sweep",
    "describe_sweep",
]
