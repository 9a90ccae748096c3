"""Vicon VSK: the layout Vicon software writes (compared with VSK files kept in public
repositories, e.g. DART's).

``Parameters`` > ``Parameter NAME= VALUE=`` for every coordinate; ``Skeleton`` > ``Segment``
with a ``JointFree MEAN=`` (6 values) ``COVARIANCE=`` (36); ``MarkerSet`` > ``Markers`` >
``Marker NAME= SEGMENT= RGB= POSITION=`` (three parameter names) ``COVARIANCE=`` (9 values)
``RADIUS=``; ``Sticks`` > ``Stick MARKER1= MARKER2= RGB=``.  A VSK carries no identification
tolerance (Vicon's are system settings).
"""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from starforge.colours import body_colour
from starforge.errors import StarforgeError
from starforge.tracking.formats._common import Record, WriteContext, f2s, num, parse_xml, points_of, xml_bytes

SUFFIX = ".vsk"
#: what a VSK carries besides its points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset({"marker_names", "marker_mm"})


def vsk_xml(
    name: str,
    P,
    marker_radius_mm: float = 2.0,
    colour: tuple[int, int, int] = (255, 0, 0),
    marker_names=None,
) -> bytes:
    """Vicon VSK for one body (segment ``name``, markers ``marker_names`` or ``M1`` .. ``Mn``), mm.
    A marker's parameters are named ``<marker>_<body>_X`` with blanks replaced (POSITION lists
    them separated by blanks)."""
    P = np.asarray(P, dtype=float)
    labels = list(marker_names) if marker_names else [f"M{i + 1}" for i in range(len(P))]
    rgb = " ".join(map(str, colour))
    root = ET.Element("KinematicModel")
    params = ET.SubElement(root, "Parameters")
    sk = ET.SubElement(root, "Skeleton")
    lo, hi = P.min(axis=0), P.max(axis=0)
    seg = ET.SubElement(
        sk,
        "Segment",
        NAME=name,
        POSITION="0 0 0",
        ORIENTATION="0 0 0",
        BOUNDS=" ".join(f2s(v) for v in (*lo, *hi)),
        RGB=rgb,
    )
    cov = np.diag([1.0, 1.0, 1.0, 1e8, 1e8, 1e8])  # rotations free, translations free (as Vicon writes)
    ET.SubElement(seg, "JointFree", MEAN="0 0 0 0 0 0", COVARIANCE=" ".join(f"{v:.6f}" for v in cov.ravel()))
    ms = ET.SubElement(root, "MarkerSet", NAME=name)
    mk = ET.SubElement(ms, "Markers")
    for i, p in enumerate(P):
        m = labels[i]
        pnames = [f"{'_'.join(m.split())}_{'_'.join(name.split())}_{c}" for c in "XYZ"]
        for pn, v in zip(pnames, p, strict=True):
            ET.SubElement(params, "Parameter", NAME=pn, VALUE=f2s(v))
        ET.SubElement(
            mk,
            "Marker",
            NAME=m,
            SEGMENT=name,
            RGB=rgb,
            POSITION=" ".join(pnames),
            COVARIANCE=" ".join(f"{v:.6f}" for v in np.eye(3).ravel()),
            RADIUS=f2s(marker_radius_mm),
        )
    st = ET.SubElement(ms, "Sticks")
    for i, j in itertools.combinations(range(len(P)), 2):
        ET.SubElement(st, "Stick", MARKER1=labels[i], MARKER2=labels[j], RGB=rgb)
    return xml_bytes(root)


def write(name: str, P, ctx: WriteContext) -> bytes:
    return vsk_xml(name, P, ctx.marker_radius_mm, body_colour(ctx.index), ctx.marker_names)


def read(path) -> dict[str, np.ndarray]:
    """Rigid bodies of a Vicon VSK: {name: (n, 3) mm} (see :func:`load`)."""
    return points_of(load(path))


def load(path) -> list[Record]:
    """Rigid bodies of a Vicon VSK, one per segment that carries markers, with marker names and
    the marker diameter (``RADIUS``, when every marker of the segment states the same one).

    A marker's ``POSITION`` is in its ``SEGMENT``'s frame, so each segment is one rigid body
    (an object VSK has one segment; a skeleton VSK has one per limb).  Position tokens are
    numbers or parameter names (``Parameters`` > ``Parameter NAME= VALUE=``), a leading ``-``
    negating a parameter, as Vicon writes ``-HipWidth``.  Bodies are named after the marker set
    when it has one segment, ``<marker set>_<segment>`` otherwise.  Segments with fewer than 3
    markers are returned too (the caller names them in a warning).
    """
    root = parse_xml(path)
    if root.tag != "KinematicModel":
        raise StarforgeError(f"{path}: a VSK's root is KinematicModel, not {root.tag!r}")
    params: dict[str, float] = {}
    for p in root.iter("Parameter"):
        if "NAME" in p.attrib:
            value = p.attrib.get("VALUE", p.attrib.get("PRIOR"))
            params[p.attrib["NAME"]] = num(path, f"parameter {p.attrib['NAME']}", value)

    def value(tok: str, marker: str) -> float:
        if tok in params:
            return params[tok]
        if tok.startswith("-") and tok[1:] in params:
            return -params[tok[1:]]
        return num(path, f"marker {marker} POSITION token", tok)

    out: dict[str, Record] = {}
    for ms in root.iter("MarkerSet"):
        set_name = ms.attrib.get("NAME") or Path(path).stem
        groups: dict[str, list] = {}
        for m in ms.iter("Marker"):
            name = m.attrib.get("NAME", "?")
            toks = m.attrib.get("POSITION", "").split()
            if len(toks) != 3:
                raise StarforgeError(f"{path}: marker {name} needs a POSITION of 3 values, got {len(toks)}")
            radius = m.attrib.get("RADIUS")
            radius = None if radius is None else num(path, f"marker {name} RADIUS", radius)
            groups.setdefault(m.attrib.get("SEGMENT", ""), []).append(
                (name, [value(t, name) for t in toks], radius)
            )
        for seg, rows in groups.items():
            key = set_name if len(groups) == 1 or not seg else f"{set_name}_{seg}"
            if key in out:
                raise StarforgeError(f"{path}: two rigid bodies are named {key!r}")
            radii = {r for _, _, r in rows}
            radius = radii.pop() if len(radii) == 1 else None
            out[key] = Record(
                key,
                np.array([p for _, p, _ in rows], dtype=float).reshape(-1, 3),
                marker_names=tuple(n for n, _, _ in rows),
                marker_mm=None if radius is None or radius <= 0 else 2.0 * radius,
            )
    if not out:
        raise StarforgeError(f"{path} holds no VSK marker (expected MarkerSet > Markers > Marker)")
    return list(out.values())


def sniff(path, head: bytes) -> bool:
    return head.startswith(b"<") and b"KinematicModel" in head
