"""OptiTrack Motive rigid bodies: a Motive profile (``.motive``, XML) holding rigid-body assets.

Motive 2 and later keep asset definitions in profile files, and loads rigid bodies from them
(File > Import/Open; the Motive API's ``TT_LoadProfile`` / ``TT_AddRigidBodies``, which PlusLib's
OptiTrack device calls with a ``RigidBodyFile``).  Motive 1.x exported ``.tra`` files instead,
which starforge does not read.  The structure, learned from a public Rhino plugin that exports
rigid bodies as Motive profiles (RhinoNatNet's ``RigidBody.ExportMotive``):

``Profile version="1"`` > ``NodeAssets`` > one ``rigid_body version="1.1" id=`` per body with
``markers`` > ``marker id=`` > ``position`` (``x,y,z``, metres), ``size`` (marker diameter, m),
``residual``, ``label_id``; and ``properties`` > ``property`` > ``name`` / ``value`` (/
``defaultValue``) for ``NodeName`` (the asset's name), ``Color``, ``DisplayLabel``,
``MaxMarkerDeflection`` (metres: how far a marker may sit from its place), ``Smoothing``,
``AcquisitionFrames`` and ``MarkerLocation0`` .. ``MarkerLocation<n-1>`` (``x,y,z``, metres).

Coordinates are written in metres as decimal text shifted exactly from the mm value's shortest
round-trip text, so reading a file back gives the same doubles in mm.  ``MaxMarkerDeflection``
is the distance tolerance starforge derives for the noise (:mod:`starforge.tracking.tolerances`).
Not verified without Motive: that Motive opens these files (only the public plugin's structure
was available) and which of ``position`` or ``MarkerLocation`` Motive takes (both are written, equal;
the reader takes ``position`` and checks ``MarkerLocation`` agrees when both are there).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from decimal import Decimal, InvalidOperation

import numpy as np

from starforge.colours import body_colour
from starforge.errors import StarforgeError
from starforge.tracking.formats._common import (
    FIX_VALUE,
    RESAVE,
    Record,
    WriteContext,
    f2s,
    noise_note,
    num,
    parse_xml,
    points_of,
    xml_bytes,
)

SUFFIX = ".motive"
MAX_MARKERS = None
#: what a Motive rigid body carries besides its points (:data:`~starforge.tracking.formats._common.FIELDS`)
CARRIES = frozenset({"body_id", "marker_mm", "bone_length_tolerance_mm"})


def _m_text(x_mm: float) -> str:
    """Metres as decimal text, shifted exactly from the mm value's shortest round-trip text (so
    reading it back and shifting again gives the same double)."""
    return format(Decimal(f2s(x_mm)).scaleb(-3).normalize(), "f")


def _xyz_m(p_mm) -> str:
    return ",".join(_m_text(v) for v in p_mm)


def _prop(parent: ET.Element, name: str, value: str, default: str | None = None) -> None:
    p = ET.SubElement(parent, "property")
    ET.SubElement(p, "name").text = name
    ET.SubElement(p, "value").text = value
    if default is not None:
        ET.SubElement(p, "defaultValue").text = default


def motive_xml(
    name: str,
    P,
    asset_id: int = 1,
    marker_mm: float = 4.0,
    deflection_mm: float = 4.0,
    colour: tuple[int, int, int] = (255, 0, 0),
    comment: str | None = None,
) -> bytes:
    """A Motive profile holding one rigid body ``name`` with markers ``P`` (n, 3) mm."""
    P = np.asarray(P, dtype=float)
    root = ET.Element("Profile", version="1")
    assets = ET.SubElement(root, "NodeAssets")
    rb = ET.SubElement(assets, "rigid_body", version="1.1", id=str(int(asset_id)))
    markers = ET.SubElement(rb, "markers")
    for i, p in enumerate(P):
        m = ET.SubElement(markers, "marker", id=str(i))
        ET.SubElement(m, "position").text = _xyz_m(p)
        ET.SubElement(m, "size").text = _m_text(marker_mm)
        ET.SubElement(m, "residual").text = "0.0"
        ET.SubElement(m, "label_id").text = str(i)
    props = ET.SubElement(rb, "properties")
    r, g, b = colour
    _prop(props, "NodeName", name)
    _prop(props, "Color", str(r + 256 * g + 65536 * b))  # a Windows COLORREF, as the plugin writes
    _prop(props, "DisplayLabel", "true")
    _prop(props, "MaxMarkerDeflection", _m_text(deflection_mm))
    for i, p in enumerate(P):
        _prop(props, f"MarkerLocation{i}", _xyz_m(p), "0,0,0")
    return xml_bytes(root, comment)


def write(name: str, P, ctx: WriteContext) -> bytes:
    t = ctx.tolerances
    comment = noise_note(t, "MaxMarkerDeflection", "keeps", "; coordinates in metres")
    return motive_xml(
        name,
        P,
        ctx.geometry_id,
        2 * ctx.marker_radius_mm,
        t.get("bone_length_tolerance_mm", 4.0),
        body_colour(ctx.index),
        comment,
    )


def _xyz(path, what: str, text) -> list[float]:
    parts = str(text or "").split(",")
    if len(parts) != 3:
        raise StarforgeError(f"{path}: {what} needs x,y,z, got {text!r}")
    out = []
    for v in parts:
        num(path, what, v)  # a finite number, else one line naming it
        try:
            out.append(float(Decimal(v.strip()).scaleb(3)))
        except InvalidOperation:
            raise StarforgeError(f"{path}: {what} is not a number ({v!r}); {FIX_VALUE}") from None
    return out


def read(path) -> dict[str, np.ndarray]:
    """Rigid bodies of a Motive profile: {NodeName: (n, 3) mm} (metres in the file)."""
    return points_of(load(path))


def _mm(path, what: str, text) -> float | None:
    """Metres text -> mm (shifted exactly), or None when absent."""
    if text is None or not str(text).strip():
        return None
    num(path, what, text)
    return float(Decimal(str(text).strip()).scaleb(3))


def load(path) -> list[Record]:
    """Rigid bodies of a Motive profile with their asset id, marker size and
    ``MaxMarkerDeflection`` (metres in the file, mm here)."""
    root = parse_xml(path)
    out: dict[str, Record] = {}
    for rb in root.iter("rigid_body"):
        props = {
            (p.findtext("name") or "").strip(): (p.findtext("value") or "").strip()
            for p in rb.iter("property")
        }
        name = props.get("NodeName") or f"rigid_body_{rb.get('id', len(out) + 1)}"
        pts = [_xyz(path, f"{name} marker position", m.findtext("position")) for m in rb.iter("marker")]
        locs = []
        i = 0
        while f"MarkerLocation{i}" in props:
            locs.append(_xyz(path, f"{name} MarkerLocation{i}", props[f"MarkerLocation{i}"]))
            i += 1
        if not pts:
            pts = locs
        elif locs and (len(locs) != len(pts) or not np.allclose(locs, pts, atol=1e-6)):
            raise StarforgeError(f"{path}: {name}'s marker positions and MarkerLocation properties disagree; {RESAVE}")
        if name in out:
            raise StarforgeError(f"{path}: two rigid bodies are named {name!r}")
        sizes = {m.findtext("size") for m in rb.iter("marker")}
        size = _mm(path, f"{name} marker size", sizes.pop()) if len(sizes) == 1 else None
        deflection = _mm(path, f"{name} MaxMarkerDeflection", props.get("MaxMarkerDeflection"))
        ident = rb.get("id", "")
        out[name] = Record(
            name,
            np.array(pts, dtype=float).reshape(-1, 3),
            body_id=int(ident) if ident.strip().isdigit() and int(ident) < 2**31 else None,
            marker_mm=size if size and size > 0 else None,
            tolerances={} if deflection is None else {"bone_length_tolerance_mm": deflection},
        )
    if not out:
        raise StarforgeError(
            f"{path} holds no Motive rigid body (expected Profile > NodeAssets > rigid_body)"
        )
    return list(out.values())


def sniff(path, head: bytes) -> bool:
    return head.startswith(b"<") and (b"<rigid_body" in head or b"<NodeAssets" in head)
