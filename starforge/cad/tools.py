"""A lab's tools (rigid bodies of any number of markers, read from tracker files) as printable
bodies: the same bodies, mounts, files and checks as a star's, for 3 to :data:`MAX_MARKERS` markers.

A :class:`ToolSet` stands where :func:`starforge.cad.describe.describe_bodies` and
:func:`starforge.cad.export.export_family` take a family: ``spec`` (name, marker diameter, no size
limit unless one is given) and ``stars`` (each tool's id, name and marker centres).  Each tool is
moved into the family paper's placement frame (:func:`starforge.stars.boxes.place_stars`: its
minimum-volume box, the thinnest side along +y), so the plate lies under every marker, as under
a star.  The move is rigid: every distance between markers is the file's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError

#: the most markers a printed tool holds (a stem each, routed clear of the others)
MAX_MARKERS = 16
#: marker diameter when neither the file nor ``--marker`` gives one, mm
DEFAULT_MARKER_MM = 4.0


@dataclass(frozen=True)
class ToolSpec:
    """What the CAD side reads of a family's spec, for tools: ``box_mm`` None (no size limit)."""

    name: str
    marker_mm: float
    box_mm: tuple[float, float, float] | None = None
    mount: str | None = None
    marker: str | None = None
    seat: str | None = None


@dataclass(frozen=True)
class Tool:
    """One tool: ``id`` (engraved on its body), ``name`` (the file's), ``vertices`` (n, 3) mm,
    marker centres in the placement frame, in the file's order."""

    id: int
    name: str
    vertices: np.ndarray


@dataclass(frozen=True)
class ToolSet:
    """Tools as :func:`starforge.cad.export.export_family` takes a family."""

    spec: ToolSpec
    stars: tuple[Tool, ...]

    def by_id(self, ids: Sequence[int]) -> list[Tool]:
        """The tools with these ids, in that order (StarforgeError naming an unknown one)."""
        have = {t.id: t for t in self.stars}
        missing = [i for i in ids if i not in have]
        if missing:
            raise StarforgeError(
                f"no tool with id {missing[0]} (ids: {', '.join(str(t.id) for t in self.stars)}); fix --ids"
            )
        return [have[i] for i in ids]


def tool_set(
    bodies: Sequence[tuple[str, np.ndarray, int | None, float | None]],
    name: str,
    marker_mm: float | None = None,
) -> ToolSet:
    """The tools of ``bodies`` ((name, points (n, 3) mm, file id or None, file marker mm or None)
    each) as a :class:`ToolSet` named ``name``.

    ``marker_mm``: the marker diameter (``--marker``); None takes the first one a file states,
    else :data:`DEFAULT_MARKER_MM`.  Ids are the files' where every body has a distinct one, else
    1, 2, ...  Raises StarforgeError (one line) for a tool of fewer than 3 or more than
    :data:`MAX_MARKERS` markers, or with two markers closer than a marker's diameter (their
    spheres would overlap).
    """
    # the placement's box search (scipy, numba) loads here, not with the export that imports
    # :class:`Tool`: exporting a family needs neither
    from starforge.stars.boxes import place_stars

    bodies = list(bodies)
    if not bodies:
        raise StarforgeError("no rigid body to print in the input; give a tracker file that holds one")
    if marker_mm is None:
        marker_mm = next((float(m) for *_, m in bodies if m), DEFAULT_MARKER_MM)
    ids = [i for _, _, i, _ in bodies]
    if None in ids or len(set(ids)) != len(ids) or min(ids) < 1:
        ids = list(range(1, len(bodies) + 1))
    tools = []
    for (bname, P, _, _), tid in zip(bodies, ids, strict=True):
        P = np.asarray(P, dtype=float)
        if not 3 <= len(P) <= MAX_MARKERS:
            raise StarforgeError(
                f"{bname} has {len(P)} markers; a printed tool holds 3 to {MAX_MARKERS} (choose a tracker --format)"
            )
        d = np.linalg.norm(P[:, None] - P[None], axis=-1)[np.triu_indices(len(P), 1)]
        if d.min() < marker_mm:
            raise StarforgeError(
                f"{bname}: two markers are {d.min():.2f} mm apart, closer than the {marker_mm:g} mm markers; "
                f"give a smaller --marker"
            )
        placed = place_stars(P[None], [np.inf] * 3)[0][0]
        tools.append(Tool(int(tid), str(bname), placed))
    return ToolSet(ToolSpec(name=name, marker_mm=float(marker_mm)), tuple(tools))
