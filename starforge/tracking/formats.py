"""Rigid-body files that tracking software loads, with readers for the same formats.

Every writer takes bodies in mm (the body's own frame).  What each format holds, and what was
checked (``tests/test_tracking_formats.py`` enforces every element and attribute listed):

* ``qtm``: the 6DOF settings structure that Qualisys' own parsers read (QTM RT protocol
  1.21 and later; ``qualisys_cpp_sdk`` ``SettingsDeserializer::Deserialize6DOFSettings`` and the
  SDK's ``Set6DOFBodySettings`` serializer): root ``QTM_Settings`` > ``The_6D`` > one ``Body``
  per body with ``Name``, ``Enabled``, ``Color R= G= B=``, ``MaximumResidual``,
  ``MinimumMarkersInBody``, ``BoneLengthTolerance``, ``Filter Preset=``, ``Points`` > ``Point
  X= Y= Z= Virtual= PhysicalId= Name=``, ``Data_origin`` (text: origin type; ``X Y Z
  Relative_body``) and ``Data_orientation`` (same type; ``R11`` .. ``R33``, ``Relative_body``).
  Tolerances come from the family: the bone-length tolerance is half its design tolerance
  (distances of two bodies then never fall in one window), the maximum residual half that.
* ``vsk``: Vicon's VSK layout as Vicon software writes it (compared with VSK files kept in
  public repositories, e.g. DART's): ``Parameters`` > ``Parameter NAME= VALUE=`` for every
  coordinate; ``Skeleton`` > ``Segment`` with a ``JointFree MEAN=`` (6 values) ``COVARIANCE=``
  (36); ``MarkerSet`` > ``Markers`` > ``Marker NAME= SEGMENT= RGB= POSITION=`` (three parameter
  names) ``COVARIANCE=`` (9 values) ``RADIUS=``; ``Sticks`` > ``Stick MARKER1= MARKER2= RGB=``.
* ``atracsys``: Atracsys fusionTrack / spryTrack geometry ``.ini`` (the layout Atracsys' SDK
  and PlusLib read): ``[geometry]`` ``count``, ``id``; ``[fiducialN]`` ``x``, ``y``, ``z``.
  Ids are unique across a lab: ``id_start`` + index, recorded in the export summary.
* ``csv``: ``body,marker,x_mm,y_mm,z_mm``.

Coordinates are written with Python's shortest round-trip float text (``repr``), so reading a
file back gives the same doubles.
"""

from __future__ import annotations

import configparser
import csv
import io
import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from starforge.colours import body_colour
from starforge.errors import StarforgeError

TRACKER_FORMATS = ("qtm", "vsk", "atracsys", "csv")
_SUFFIX = {"qtm": ".xml", "vsk": ".vsk", "atracsys": ".ini", "csv": ".csv"}


def _f(x: float) -> str:
    return repr(float(x))


def _xml_bytes(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


def qtm_tolerances(tolerance_mm: float | None) -> tuple[float, float]:
    """(BoneLengthTolerance, MaximumResidual) in mm from a family's design tolerance: half the
    tolerance, so the windows of two bodies' distances never overlap, and the residual half of
    that; 2 mm / 1 mm when the tolerance is unknown (imported or placement bodies)."""
    if tolerance_mm is None:
        return 2.0, 1.0
    bone = round(min(max(tolerance_mm / 2.0, 0.1), 10.0), 6)
    return bone, round(bone / 2.0, 6)


def qtm_xml(
    bodies,
    bone_tolerance_mm: float = 2.0,
    max_residual_mm: float = 1.0,
    min_markers: int = 3,
    first_colour: int = 0,
) -> bytes:
    """QTM 6DOF settings for ``bodies``: list of (name, (n, 3) mm) (see the module docstring);
    body k gets colour ``first_colour + k``."""
    root = ET.Element("QTM_Settings")
    the6d = ET.SubElement(root, "The_6D")
    for k, (name, P) in enumerate(bodies):
        b = ET.SubElement(the6d, "Body")
        ET.SubElement(b, "Name").text = name
        ET.SubElement(b, "Enabled").text = "true"
        r, g, bl = body_colour(first_colour + k)
        ET.SubElement(b, "Color", R=str(r), G=str(g), B=str(bl))
        ET.SubElement(b, "MaximumResidual").text = _f(max_residual_mm)
        ET.SubElement(b, "MinimumMarkersInBody").text = str(int(min_markers))
        ET.SubElement(b, "BoneLengthTolerance").text = _f(bone_tolerance_mm)
        ET.SubElement(b, "Filter", Preset="No filter")
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
        # origin type 0: the global coordinate system, identity orientation
        ET.SubElement(b, "Data_origin", X="0", Y="0", Z="0", Relative_body="0").text = "0"
        rot = {f"R{i}{j}": ("1" if i == j else "0") for i in (1, 2, 3) for j in (1, 2, 3)}
        ET.SubElement(b, "Data_orientation", **rot, Relative_body="0").text = "0"
    return _xml_bytes(root)


def vsk_xml(name: str, P, marker_radius_mm: float = 2.0, colour: tuple[int, int, int] = (255, 0, 0)) -> bytes:
    """Vicon VSK for one body (segment ``name``, markers ``M1`` .. ``Mn``), mm."""
    P = np.asarray(P, dtype=float)
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
        BOUNDS=" ".join(_f(v) for v in (*lo, *hi)),
        RGB=rgb,
    )
    cov = np.diag([1.0, 1.0, 1.0, 1e8, 1e8, 1e8])  # rotations free, translations free (as Vicon writes)
    ET.SubElement(
        seg,
        "JointFree",
        MEAN="0 0 0 0 0 0",
        COVARIANCE=" ".join(f"{v:.6f}" for v in cov.ravel()),
    )
    ms = ET.SubElement(root, "MarkerSet", NAME=name)
    mk = ET.SubElement(ms, "Markers")
    for i, p in enumerate(P):
        m = f"M{i + 1}"
        pnames = [f"{m}_{name}_{c}" for c in "XYZ"]
        for pn, v in zip(pnames, p, strict=True):
            ET.SubElement(params, "Parameter", NAME=pn, VALUE=_f(v))
        ET.SubElement(
            mk,
            "Marker",
            NAME=m,
            SEGMENT=name,
            RGB=rgb,
            POSITION=" ".join(pnames),
            COVARIANCE=" ".join(f"{v:.6f}" for v in np.eye(3).ravel()),
            RADIUS=_f(marker_radius_mm),
        )
    st = ET.SubElement(ms, "Sticks")
    for i, j in itertools.combinations(range(len(P)), 2):
        ET.SubElement(st, "Stick", MARKER1=f"M{i + 1}", MARKER2=f"M{j + 1}", RGB=rgb)
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


def write_bodies(bodyset, formats, out_dir: Path, id_start: int = 1) -> dict:
    """Write every body of ``bodyset`` (a :class:`~starforge.tracking.bodies.BodySet`) in each
    format into ``out_dir/<format>/<name><suffix>``.

    Returns a summary: the paths written, the Atracsys id of every body (``id_start`` + index,
    unique across a lab that gives each family its own range) and the QTM tolerances used.
    """
    from starforge.io import atomic_write_bytes, atomic_write_text

    if not (isinstance(id_start, int) and 0 <= id_start <= 2**31 - 1 - len(bodyset.bodies)):
        raise StarforgeError(
            f"id_start must be an integer in [0, {2**31 - 1 - len(bodyset.bodies)}], got {id_start!r}"
        )
    out_dir = Path(out_dir)
    radius = (bodyset.marker_mm or 4.0) / 2.0
    bone, resid = qtm_tolerances(bodyset.tolerance_mm)
    ids = {b.name: id_start + k for k, b in enumerate(bodyset.bodies)}
    written: list[Path] = []
    for fmt in parse_formats(formats):
        folder = out_dir / fmt
        for k, b in enumerate(bodyset.bodies):
            path = folder / f"{b.name}{_SUFFIX[fmt]}"
            if fmt == "qtm":
                atomic_write_bytes(path, qtm_xml([(b.name, b.points_mm)], bone, resid, first_colour=k))
            elif fmt == "vsk":
                atomic_write_bytes(path, vsk_xml(b.name, b.points_mm, radius, body_colour(k)))
            elif fmt == "atracsys":
                atomic_write_text(path, atracsys_ini(ids[b.name], b.points_mm))
            else:
                atomic_write_text(path, plain_csv([(b.name, b.points_mm)]))
            written.append(path)
    return {
        "files": [str(p.relative_to(out_dir)) for p in written],
        "atracsys_ids": ids,
        "qtm": {"bone_length_tolerance_mm": bone, "maximum_residual_mm": resid},
    }


def write_rigid_bodies(input_json_path, formats: list[str], out_dir: Path, id_start: int = 1) -> dict:
    """Read a family, placement or tracker file (or several) and write its bodies (see
    :func:`write_bodies`).  Raises StarforgeError on a bad input file or an unknown format."""
    from starforge.tracking.bodies import load_bodies

    fmts = parse_formats(formats)
    return write_bodies(load_bodies(input_json_path), fmts, Path(out_dir), id_start)


# --- readers ---------------------------------------------------------------------------------


def _parse_xml(path) -> ET.Element:
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise StarforgeError(f"{path} is not valid XML ({exc})") from None


def _num(path, what: str, text) -> float:
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise StarforgeError(f"{path}: {what} is not a number ({text!r})") from None
    if not np.isfinite(v):
        raise StarforgeError(f"{path}: {what} is not finite ({text!r})")
    return v


def read_qtm(path) -> dict[str, np.ndarray]:
    """Bodies of a QTM 6DOF settings file (``The_6D`` > ``Body``) or a QTM body file
    (``Bodies`` > ``Body``): {name: (n, 3) mm}.  Point coordinates as attributes or children;
    virtual points are skipped (no marker there)."""
    root = _parse_xml(path)
    out = {}
    for b in root.iter("Body"):
        name = (b.findtext("Name") or "").strip() or f"body{len(out) + 1}"
        pts = []
        for p in b.iter("Point"):
            if p.attrib.get("Virtual", "0") not in ("0", "false", ""):
                continue
            if "X" in p.attrib:
                pts.append([_num(path, f"{name} point {c}", p.attrib.get(c)) for c in "XYZ"])
            else:
                pts.append([_num(path, f"{name} point {c}", p.findtext(c)) for c in "XYZ"])
        out[name] = np.array(pts, dtype=float).reshape(-1, 3)
    if not out:
        raise StarforgeError(f"{path} holds no QTM Body")
    return out


def read_vsk(path) -> dict[str, np.ndarray]:
    """Markers of a Vicon VSK: {marker set name: (n, 3) mm}; parameter names in POSITION
    resolved (a leading ``-`` negates, as Vicon writes ``-HipWidth``)."""
    root = _parse_xml(path)
    params = {}
    for p in root.iter("Parameter"):
        if "NAME" in p.attrib:
            params[p.attrib["NAME"]] = _num(
                path, f"parameter {p.attrib['NAME']}", p.attrib.get("VALUE", p.attrib.get("PRIOR"))
            )
    out = {}
    for ms in root.iter("MarkerSet"):
        pts = []
        for m in ms.iter("Marker"):
            vals = []
            for tok in m.attrib.get("POSITION", "").split():
                sign, key = (-1.0, tok[1:]) if tok.startswith("-") and tok[1:] in params else (1.0, tok)
                if key in params:
                    vals.append(sign * params[key])
                else:
                    vals.append(_num(path, f"marker {m.attrib.get('NAME')} position", tok))
            if len(vals) != 3:
                raise StarforgeError(f"{path}: marker {m.attrib.get('NAME')} has no 3-value POSITION")
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
        if not 1 <= n <= 1000:
            raise ValueError(f"count {n} out of range")
        pts = [[cp.getfloat(f"fiducial{i}", c) for c in "xyz"] for i in range(n)]
    except (configparser.Error, ValueError, UnicodeDecodeError) as exc:
        raise StarforgeError(
            f"{path} is not an Atracsys geometry file ({exc.__class__.__name__}: {exc})"
        ) from None
    return {Path(path).stem: np.array(pts, dtype=float).reshape(-1, 3)}


def read_csv(path) -> dict[str, np.ndarray]:
    """``body,marker,x_mm,y_mm,z_mm`` rows: {body: (n, 3) mm} in marker order."""
    rows: dict[str, list] = {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            for r in csv.DictReader(fh):
                rows.setdefault(r["body"], []).append(
                    (
                        int(r["marker"]),
                        [_num(path, f"{r['body']} {c}", r[c]) for c in ("x_mm", "y_mm", "z_mm")],
                    )
                )
    except (KeyError, ValueError, TypeError, UnicodeDecodeError) as exc:
        raise StarforgeError(
            f"{path} is not a body,marker,x_mm,y_mm,z_mm table ({exc.__class__.__name__}: {exc})"
        ) from None
    if not rows:
        raise StarforgeError(f"{path} holds no body rows")
    return {k: np.array([p for _, p in sorted(v)], dtype=float).reshape(-1, 3) for k, v in rows.items()}


def sniff_format(path) -> str | None:
    """The tracker format of a file by its content (then its suffix), or None."""
    path = Path(path)
    head = path.read_bytes()[:4096].lstrip()
    if head.startswith(b"<"):
        text = head.decode("utf-8", "replace")
        if "KinematicModel" in text:
            return "vsk"
        if "The_6D" in text or "QTM_" in text or "<Bodies" in text:
            return "qtm"
        return {".vsk": "vsk", ".xml": "qtm"}.get(path.suffix.lower())
    if b"[geometry]" in head:
        return "atracsys"
    if head.startswith(b"body,marker"):
        return "csv"
    return None


READERS = {"qtm": read_qtm, "vsk": read_vsk, "atracsys": read_atracsys, "csv": read_csv}
