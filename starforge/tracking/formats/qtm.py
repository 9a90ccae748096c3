"""Qualisys QTM 6DOF bodies: the settings structure Qualisys' own parsers read.

QTM RT protocol 1.21 and later (``qualisys_cpp_sdk`` ``SettingsDeserializer::Deserialize6DOFSettings``
and the SDK's ``Set6DOFBodySettings`` serializer): root ``QTM_Settings`` > ``The_6D`` > one
``Body`` per body with ``Name``, ``Enabled``, ``Color R= G= B=``, ``MaximumResidual``,
``MinimumMarkersInBody``, ``BoneLengthTolerance``, ``Filter Preset=``, ``Points`` > ``Point X=
Y= Z= Virtual= PhysicalId= Name=``, ``Data_origin`` (text: origin type; ``X Y Z Relative_body``)
and ``Data_orientation`` (same type; ``R11`` .. ``R33``, ``Relative_body``).  The tolerances come
from the export context (:func:`starforge.tracking.tolerances.export_tolerances`: the noise the
file assumes and the bodies' margins); a comment in the file names the noise.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from starforge.colours import body_colour
from starforge.errors import StarforgeError
from starforge.tracking.formats._common import (
    Record,
    WriteContext,
    f2s,
    noise_note,
    num,
    parse_xml,
    points_of,
    xml_bytes,
)

SUFFIX = ".xml"
#: what a QTM body carries besides its points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset({"marker_names", "bone_length_tolerance_mm", "maximum_residual_mm", "min_markers"})


def qtm_xml(
    bodies,
    bone_tolerance_mm: float = 2.0,
    max_residual_mm: float = 1.0,
    min_markers: int = 3,
    first_colour: int = 0,
    comment: str | None = None,
    marker_names=None,
) -> bytes:
    """QTM 6DOF settings for ``bodies``: list of (name, (n, 3) mm); body k gets colour
    ``first_colour + k``.  ``marker_names``: one tuple of point names per body (None: QTM's own
    ``<body> - <k>``)."""
    root = ET.Element("QTM_Settings")
    the6d = ET.SubElement(root, "The_6D")
    for k, (name, P) in enumerate(bodies):
        b = ET.SubElement(the6d, "Body")
        ET.SubElement(b, "Name").text = name
        ET.SubElement(b, "Enabled").text = "true"
        r, g, bl = body_colour(first_colour + k)
        ET.SubElement(b, "Color", R=str(r), G=str(g), B=str(bl))
        ET.SubElement(b, "MaximumResidual").text = f2s(max_residual_mm)
        ET.SubElement(b, "MinimumMarkersInBody").text = str(int(min_markers))
        ET.SubElement(b, "BoneLengthTolerance").text = f2s(bone_tolerance_mm)
        ET.SubElement(b, "Filter", Preset="No filter")
        pts = ET.SubElement(b, "Points")
        names = (marker_names or [None] * len(bodies))[k] or [f"{name} - {i + 1}" for i in range(len(P))]
        for i, p in enumerate(np.asarray(P, dtype=float)):
            ET.SubElement(
                pts,
                "Point",
                X=f2s(p[0]),
                Y=f2s(p[1]),
                Z=f2s(p[2]),
                Virtual="0",
                PhysicalId="0",
                Name=names[i],
            )
        # origin type 0: the global coordinate system, identity orientation
        ET.SubElement(b, "Data_origin", X="0", Y="0", Z="0", Relative_body="0").text = "0"
        rot = {f"R{i}{j}": ("1" if i == j else "0") for i in (1, 2, 3) for j in (1, 2, 3)}
        ET.SubElement(b, "Data_orientation", **rot, Relative_body="0").text = "0"
    return xml_bytes(root, comment)


def write(name: str, P, ctx: WriteContext) -> bytes:
    t = ctx.tolerances
    comment = noise_note(t, "BoneLengthTolerance and MaximumResidual")
    return qtm_xml(
        [(name, P)],
        t.get("bone_length_tolerance_mm", 2.0),
        t.get("maximum_residual_mm", 1.0),
        ctx.min_markers,
        first_colour=ctx.index,
        comment=comment,
        marker_names=[ctx.marker_names],
    )


def read(path) -> dict[str, np.ndarray]:
    """Bodies of a QTM file: {name: (n, 3) mm} (see :func:`load`)."""
    return points_of(load(path))


def _tolerance(path, b, tag: str, name: str) -> float | None:
    text = b.findtext(tag)
    return None if text is None or not text.strip() else num(path, f"{name} {tag}", text)


def load(path) -> list[Record]:
    """Bodies of a QTM file with their point names, tolerances and minimum markers.

    Reads the 6DOF settings structure (``The_6D`` > ``Body`` > ``Points`` > ``Point X= Y= Z=``,
    QTM RT protocol 1.21 and later), older body files (``Bodies`` > ``Body`` with the same
    points) and the pre-1.21 layout (``Body`` > ``Bone`` with ``X``/``Y``/``Z`` children).
    Virtual points (``Virtual`` not 0) carry no marker and are skipped.
    """
    root = parse_xml(path)
    out: dict[str, Record] = {}
    for b in root.iter("Body"):
        name = (b.findtext("Name") or "").strip() or f"body{len(out) + 1}"
        pts, names = [], []
        points = list(b.iter("Point"))
        for p in points:
            if p.attrib.get("Virtual", "0").strip().lower() not in ("0", "false", ""):
                continue
            names.append(p.attrib.get("Name", ""))
            if "X" in p.attrib:
                pts.append([num(path, f"{name} point {c}", p.attrib.get(c)) for c in "XYZ"])
            else:
                pts.append([num(path, f"{name} point {c}", p.findtext(c)) for c in "XYZ"])
        if not points:
            for bone in b.findall("Bone"):
                pts.append([num(path, f"{name} bone {c}", bone.findtext(c)) for c in "XYZ"])
        if name in out:
            raise StarforgeError(f"{path}: two bodies are named {name!r}")
        tags = (
            ("bone_length_tolerance_mm", "BoneLengthTolerance"),
            ("maximum_residual_mm", "MaximumResidual"),
        )
        tol = {key: v for key, tag in tags if (v := _tolerance(path, b, tag, name)) is not None}
        least = _tolerance(path, b, "MinimumMarkersInBody", name)
        out[name] = Record(
            name,
            np.array(pts, dtype=float).reshape(-1, 3),
            marker_names=tuple(names) if names and all(names) else None,
            tolerances=tol,
            min_markers=None if least is None else int(least),
        )
    if not out:
        raise StarforgeError(f"{path} holds no QTM Body (expected The_6D > Body > Points > Point)")
    return list(out.values())


def sniff(path, head: bytes) -> bool:
    if head.startswith(b"<"):
        text = head.decode("utf-8", "replace")
        return "The_6D" in text or "QTM_" in text or "<Bodies" in text
    return False
