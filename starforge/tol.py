"""One place for geometric tolerances (in the spirit of ``trimesh.constants.tol``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tolerance:
    """Geometric epsilons; lengths in mm unless the name says otherwise.

    Attributes
    ----------
    length_mm : float
        Two lengths closer than this are the same length (float noise, not design tolerance).
    grid : float
        Relative slack when snapping a length to a pool grid (fraction of the step).
    volume_mm3 : float
        A tetrahedron with a smaller volume is degenerate (flat).
    zero : float
        Generic floating-point zero for unitless quantities.
    reproduce_mm : float
        Trilateration must reproduce edge lengths to within this.
    box_rel : float
        Relative tolerance when comparing box extents against a size limit.
    compare_mm : float
        Slack when comparing lengths computed from stored coordinates (rounded to 1e-9 mm in
        the JSON files) against a rule's threshold: far below any physical meaning.
    """

    length_mm: float = 1e-9
    grid: float = 1e-6
    volume_mm3: float = 1e-9
    zero: float = 1e-12
    reproduce_mm: float = 1e-9
    box_rel: float = 1e-9
    compare_mm: float = 1e-6


tol = Tolerance()
