"""Rigid-body files that tracking software loads, with readers that round-trip them exactly.

Every writer takes bodies in mm (the body's own frame) and writes one file per body:

* ``qtm``: Qualisys QTM body XML (the file QTM's 6DOF "Load bodies" reads): root
  ``QTM_Body_File_Ver_1.00`` > ``Bodies`` > ``Body`` with ``Name``, ``Enabled``, ``Color``,
  ``MaximumResidual``, ``MinimumMarkersInBody``, ``BoneLengthTolerance`` and
  ``Points`` > ``Point X= Y= Z= Virtual= PhysicalId= Name=``.
* ``vsk``: Vicon VSK (XML ``KinematicModel``): ``Parameters``, ``Skeleton`` > ``Segment``
  (with a ``JointFree`` to the world), ``MarkerSet`` > ``Markers`` > ``Marker NAME="M1" POSITION="x
  y z" SEGMENT= ...`` and ``Sticks`` between consecutive markers.
* ``atracsys``: Atracsys fusionTrack / spryTrack geometry ``.ini``: ``[geometry]`` ``count``,
  ``id``, then ``[fiducialN]`` ``x``, ``y``, ``z``.
* ``csv``: ``body,marker,x_mm,y_mm,z_mm``.

Coordinates are written with Python's shortest round-trip float text (``repr``), so reading
a file back gives the same doubles.
"""

from __future__ import annotations

import configparser
import csv
import io
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError

TRACKER_FORMATS = ("qtm", "vsk", "atracsys", "csv")
_SUFFIX = {"qtm": ".xml", "vsk": ".vsk", "atracsys": ".ini", "csv": ".csv"}
_COLORS = [(255, 0, 0), (0, 160, 0), (0, 0, 255), (230, 160, 0), (160, 0, 160), (0, 160, 160)]


def _f(x: float) -> str:
    return repr(float(x))


def _xml_bytes(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def qtm_xml(bodies, max_residual_mm: float = 10.0, bone_tolerance_mm: float = 5.0) -> bytes:
    """QTM body file for ``bodies``: list of (name, (n, 3) mm)."""
    root = ET.Element("QTM_Body_File_Ver_1.00")
    bs = ET.SubElement(root, "Bodies")
    for k, (name, P) in enumerate(bodies):
        b = ET.SubElement(bs, "Body")
        ET.SubElement(b, "Name").text = name
        ET.SubElement(b, "Enabled").text = "true"
        r, g, bl = _COLORS[k % len(_COLORS)]
        ET.SubElement(b, "Color", R=str(r), G=str(g), B=str(bl))
        ET.SubElement(b, "MaximumResidual").text = _f(max_residual_mm)
        ET.SubElement(b, "MinimumMarkersInBody").text = "3"
        ET.SubElement(b, "BoneLengthTolerance").text = _f(bone_tolerance_mm)
        pts = ET.SubElement(b, "Points")
        for i, p in enumerate(np.asarray(P, dtype=float)):
            ET.SubElement(
                pts,
                "Point",
                X=_f(p[0]),
                Y=_f(p[1]),
                Z=_f(p[2]),
                Virtual="0",
                PhysicalId="0",
                Name=f"{name} - {i + 1}",
            )
    return _xml_bytes(root)


def vsk_xml(name: str, P, marker_radius_mm: float = 2.0) -> bytes:
    """Vicon VSK for one body (segment ``name``, markers ``M1`` .. ``Mn``), mm."""
    P = np.asarray(P, dtype=float)
    root = ET.Element("KinematicModel")
    params = ET.SubElement(root, "Parameters")
    sk = ET.SubElement(root, "Skeleton")
    seg = ET.SubElement(
        sk, "Segment", NAME=name, POSITION="0 0 0", ORIENTATION="0 0 0", BOUNDS="0 0 0 0 0 0", RGB="255 0 0"
    )
    ET.SubElement(seg, "JointFree", NAME=f"World_{name}")
    ms = ET.SubElement(root, "MarkerSet", NAME=name)
    mk = ET.SubElement(ms, "Markers")
    for i, p in enumerate(P):
        m = f"M{i + 1}"
        for c, v in zip("xyz", p, strict=True):
            ET.SubElement(params, "Parameter", NAME=f"{name}_{m}_{c}", PRIOR=_f(v), VALUE=_f(v))
        ET.SubElement(
            mk,
            "Marker",
            STATUS="required",
            NAME=m,
            POSITION=" ".join(_f(v) for v in p),
            SEGMENT=name,
            COVARIANCE="0 0 0 0 0 0",
            RADIUS=_f(marker_radius_mm),
            RGB="255 0 0",
        )
    st = ET.SubElement(ms, "Sticks")
    for i in range(len(P)):
        j = (i + 1) % len(P)
        if len(P) > 2 or i == 0:
            ET.SubElement(
                st, "Stick", MARKER1=f"M{i + 1}", MARKER2=f"M{j + 1}", RGB1="255 0 0", RGB2="255 0 0"
            )
    return _xml_bytes(root)


def atracsys_ini(geometry_id: int, P) -> str:
    """Atracsys geometry ``.ini`` text, mm."""
    P = np.asarray(P, dtype=float)
    lines = ["[geometry]", f"count={len(P)}", f"id={int(geometry_id)}"]
    for i, p in enumerate(P):
        lines += [f"[fiducial{i}]", f"x={_f(p[0])}", f"y={_f(p[1])}", f"z={_f(p[2])}"]
    return "\n".join(lines) + "\n"


def plain_csv(bodies) -> str:
    """``body,marker,x_mm,y_mm,z_mm`` rows (marker numbered from 1)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["body", "marker", "x_mm", "y_mm", "z_mm"])
    for name, P in bodies:
        for i, p in enumerate(np.asarray(P, dtype=float)):
            w.writerow([name, i + 1, _f(p[0]), _f(p[1]), _f(p[2])])
    return buf.getvalue()


def parse_formats(formats) -> list[str]:
    """``"qtm,vsk"`` or a list -> validated, de-duplicated list; StarforgeError names the known ones."""
    if isinstance(formats, str):
        formats = formats.split(",")
    out: list[str] = []
    for f in formats:
        f = str(f).strip().lower()
        if not f:
            continue
        if f not in TRACKER_FORMATS:
            raise StarforgeError(f"unknown tracker format {f!r}; known: {', '.join(TRACKER_FORMATS)}")
        if f not in out:
            out.append(f)
    if not out:
        raise StarforgeError(f"no tracker format given; known: {', '.join(TRACKER_FORMATS)}")
    return out


def write_bodies(bodyset, formats, out_dir: Path) -> list[Path]:
    """Write every body of ``bodyset`` (a :class:`~starforge.tracking.bodies.BodySet`) in each
    format into ``out_dir/<format>/<name><suffix>``; returns the paths written."""
    from starforge.io import atomic_write_bytes, atomic_write_text

    out_dir = Path(out_dir)
    radius = (bodyset.marker_mm or 4.0) / 2.0
    written: list[Path] = []
    for fmt in parse_formats(formats):
        folder = out_dir / fmt
        for b in bodyset.bodies:
            path = folder / f"{b.name}{_SUFFIX[fmt]}"
            if fmt == "qtm":
                atomic_write_bytes(path, qtm_xml([(b.name, b.points_mm)]))
            elif fmt == "vsk":
                atomic_write_bytes(path, vsk_xml(b.name, b.points_mm, radius))
            elif fmt == "atracsys":
                atomic_write_text(path, atracsys_ini(b.id, b.points_mm))
            else:
                atomic_write_text(path, plain_csv([(b.name, b.points_mm)]))
            written.append(path)
    return written


def write_rigid_bodies(input_json_path, formats: list[str], out_dir: Path) -> list[Path]:
    """Read a family or placement JSON (or a list of placement JSONs) and write its bodies.

    One file per body per format under ``out_dir`` (the caller's staging folder), mm.
    Raises StarforgeError on a bad input file or an unknown format.
    """
    from starforge.tracking.bodies import load_bodies

    fmts = parse_formats(formats)
    return write_bodies(load_bodies(input_json_path), fmts, Path(out_dir))


# --- readers ---------------------------------------------------------------------------------


def _parse_xml(path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise StarforgeError(f"{path} is not valid XML ({exc})") from None


def read_qtm(path) -> dict[str, np.ndarray]:
    """Bodies of a QTM body XML file: {name: (n, 3) mm}.  Accepts X/Y/Z as attributes or children."""
    root = _parse_xml(path)
    out = {}
    for b in root.iter("Body"):
        name = (b.findtext("Name") or "").strip()
        pts = []
        for p in b.iter("Point"):
            if "X" in p.attrib:
                pts.append([float(p.attrib[c]) for c in "XYZ"])
            else:
                pts.append([float(p.findtext(c)) for c in "XYZ"])
        out[name] = np.array(pts, dtype=float).reshape(-1, 3)
    if not out:
        raise StarforgeError(f"{path} holds no QTM Body")
    return out


def read_vsk(path) -> dict[str, np.ndarray]:
    """Markers of a Vicon VSK: {marker set name: (n, 3) mm}; parameter names in POSITION resolved."""
    root = _parse_xml(path)
    params = {
        p.attrib["NAME"]: float(p.attrib.get("VALUE", p.attrib.get("PRIOR", "nan")))
        for p in root.iter("Parameter")
        if "NAME" in p.attrib
    }
    out = {}
    for ms in root.iter("MarkerSet"):
        pts = []
        for m in ms.iter("Marker"):
            vals = []
            for tok in m.attrib["POSITION"].split():
                try:
                    vals.append(float(tok))
                except ValueError:
                    vals.append(params[tok])
            pts.append(vals)
        out[ms.attrib.get("NAME", Path(path).stem)] = np.array(pts, dtype=float).reshape(-1, 3)
    if not out:
        raise StarforgeError(f"{path} holds no VSK MarkerSet")
    return out


def read_atracsys(path) -> dict[str, np.ndarray]:
    """An Atracsys geometry ``.ini``: {file stem: (count, 3) mm}."""
    cp = configparser.ConfigParser()
    try:
        cp.read_string(Path(path).read_text(encoding="utf-8"))
        n = cp.getint("geometry", "count")
        pts = [[cp.getfloat(f"fiducial{i}", c) for c in "xyz"] for i in range(n)]
    except (configparser.Error, ValueError) as exc:
        raise StarforgeError(
            f"{path} is not an Atracsys geometry file ({exc.__class__.__name__}: {exc})"
        ) from None
    return {Path(path).stem: np.array(pts, dtype=float).reshape(-1, 3)}


def read_csv(path) -> dict[str, np.ndarray]:
    """``body,marker,x_mm,y_mm,z_mm`` rows: {body: (n, 3) mm} in marker order."""
    rows: dict[str, list] = {}
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            rows.setdefault(r["body"], []).append(
                (int(r["marker"]), [float(r[c]) for c in ("x_mm", "y_mm", "z_mm")])
            )
    return {k: np.array([p for _, p in sorted(v)], dtype=float).reshape(-1, 3) for k, v in rows.items()}


READERS = {"qtm": read_qtm, "vsk": read_vsk, "atracsys": read_atracsys, "csv": read_csv}
