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
  Tolerances come from the bodies' margins (:func:`qtm_tolerances`): the bone-length
  tolerance is half the smallest one-marker-hidden margin, the maximum residual half that.
  Every body gets its own colour.
* ``vsk``: Vicon's VSK layout as Vicon software writes it (compared with VSK files kept in
  public repositories, e.g. DART's): ``Parameters`` > ``Parameter NAME= VALUE=`` for every
  coordinate; ``Skeleton`` > ``Segment`` with a ``JointFree MEAN=`` (6 values) ``COVARIANCE=``
  (36); ``MarkerSet`` > ``Markers`` > ``Marker NAME= SEGMENT= RGB= POSITION=`` (three parameter
  names) ``COVARIANCE=`` (9 values) ``RADIUS=``; ``Sticks`` > ``Stick MARKER1= MARKER2= RGB=``.
* ``atracsys``: Atracsys fusionTrack / spryTrack geometry ``.ini`` (the layout Atracsys' SDK
  and PlusLib read): ``[geometry]`` ``count``, ``id``; ``[fiducialN]`` ``x``, ``y``, ``z``,
  written ``key=value`` with no spaces (Atracsys' INI code matches keys verbatim), at most
  :data:`ATRACSYS_MAX_FIDUCIALS` fiducials.  Ids are unique across a lab: ``id_start`` +
  index, recorded in the export summary.
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

#: fiducials one Atracsys geometry may hold (``FTK_MAX_FIDUCIALS`` in Atracsys' SDK headers; the
#: INI loader Atracsys ships, as kept in PlusLib, writes ``count`` points into an array this long)
ATRACSYS_MAX_FIDUCIALS = 6


def _f(x: float) -> str:
    return repr(float(x))


def _xml_bytes(root: ET.Element) -> bytes:
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True) + b"\n"


#: the QTM bone-length tolerance starforge writes stays within these, mm
QTM_BONE_MM = (0.1, 5.0)


def qtm_tolerances(points_list) -> dict:
    """QTM's two identification tolerances for a set of bodies (list of (n, 3) mm), derived from
    the bodies' own margins.

    QTM includes a marker in a body when every distance to the body's other markers is within
    ``BoneLengthTolerance`` of the definition, and reports a pose only when the fit residual is
    under ``MaximumResidual``.  Starforge sets the bone tolerance to half the bodies' smallest
    identification margin with one marker hidden
    (:func:`starforge.tracking.identify.drop1_margin_mm`): a measured distance then matches its
    own value with the same slack it keeps from every other body's (the midpoint), and the
    maximum residual to half the bone tolerance (starforge's choice), both clipped to
    :data:`QTM_BONE_MM`.  Returns the margin, both tolerances and a note when the bone tolerance
    is under three standard deviations of a distance measured with 0.2 mm noise per axis.
    """
    from starforge.tracking.identify import build_library, drop1_margin_mm

    margin = drop1_margin_mm(build_library(points_list))
    bone = round(float(np.clip(margin / 2.0, *QTM_BONE_MM)), 6)
    out = {
        "margin_mm": round(margin, 6),
        "bone_length_tolerance_mm": bone,
        "maximum_residual_mm": round(bone / 2, 6),
    }
    sigma_d = 0.2 * np.sqrt(2.0)  # a distance's noise with 0.2 mm per axis on both ends
    if bone < 3 * sigma_d:
        out["note"] = (
            f"bone length tolerance {bone:g} mm is under 3 sigma ({3 * sigma_d:.2f} mm) of a distance measured "
            f"with 0.2 mm noise per axis: QTM will leave some markers out in noisy frames; bodies with larger "
            f"margins allow a larger tolerance"
        )
    return out


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


def check_exportable(bodyset, formats, id_start: int = 1) -> None:
    """Refuse, before anything is written, what a format cannot hold: an Atracsys geometry has
    at most :data:`ATRACSYS_MAX_FIDUCIALS` fiducials and a 32-bit id."""
    n = len(bodyset.bodies)
    if not (isinstance(id_start, int) and 0 <= id_start <= 2**31 - 1 - n):
        raise StarforgeError(f"id_start must be an integer in [0, {2**31 - 1 - n}], got {id_start!r}")
    if "atracsys" in formats:
        big = [b for b in bodyset.bodies if b.n_markers > ATRACSYS_MAX_FIDUCIALS]
        if big:
            raise StarforgeError(
                f"an Atracsys geometry holds at most {ATRACSYS_MAX_FIDUCIALS} fiducials; {big[0].name} has "
                f"{big[0].n_markers} (and {len(big) - 1} more bodies are too large); leave out atracsys"
            )


def write_bodies(bodyset, formats, out_dir: Path, id_start: int = 1) -> dict:
    """Write every body of ``bodyset`` (a :class:`~starforge.tracking.bodies.BodySet`) in each
    format into ``out_dir/<format>/<name><suffix>``.

    Returns a summary: the paths written, the Atracsys id of every body (``id_start`` + index,
    unique across a lab that gives each family its own range) and the QTM tolerances used
    (:func:`qtm_tolerances`, from these bodies' margins).
    """
    from starforge.io import atomic_write_bytes, atomic_write_text

    formats = parse_formats(formats)
    check_exportable(bodyset, formats, id_start)
    out_dir = Path(out_dir)
    radius = (bodyset.marker_mm or 4.0) / 2.0
    qtm = qtm_tolerances([b.points_mm for b in bodyset.bodies])
    bone, resid = qtm["bone_length_tolerance_mm"], qtm["maximum_residual_mm"]
    ids = {b.name: id_start + k for k, b in enumerate(bodyset.bodies)}
    written: list[Path] = []
    for fmt in formats:
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
        "qtm": qtm,
    }


def write_rigid_bodies(input_json_path, formats: list[str], out_dir: Path, id_start: int = 1) -> dict:
    """Read a family, placement or tracker file (or several) and write its bodies (see
    :func:`write_bodies`).  Raises StarforgeError on a bad input file or an unknown format."""
    from starforge.tracking.bodies import load_bodies

    fmts = parse_formats(formats)
    return write_bodies(load_bodies(input_json_path), fmts, Path(out_dir), id_start)


# --- readers ---------------------------------------------------------------------------------
#
# Each reader returns {body name: (n, 3) mm} in file order.  The formats all hold millimetres
# (QTM's 6DOF settings, Vicon's VSK and Atracsys' geometry files are mm by definition; the body
# CSV says so in its header, and a CSV with x_m, y_m, z_m columns is converted).  Anything a
# reader cannot make sense of raises StarforgeError naming the file and what is wrong.

#: tracker files larger than this are refused before parsing (a body file is a few kB)
MAX_FILE_BYTES = 64 * 1024**2


def _check_size(path) -> None:
    size = Path(path).stat().st_size
    if size > MAX_FILE_BYTES:
        from starforge.budget import format_bytes

        raise StarforgeError(
            f"{path} is {format_bytes(size)}; a tracker body file is at most {format_bytes(MAX_FILE_BYTES)}"
        )


def _parse_xml(path) -> ET.Element:
    _check_size(path)
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
    """Bodies of a QTM file: {name: (n, 3) mm}.

    Reads the 6DOF settings structure (``The_6D`` > ``Body`` > ``Points`` > ``Point X= Y= Z=``,
    QTM RT protocol 1.21 and later), older body files (``Bodies`` > ``Body`` with the same
    points) and the pre-1.21 layout (``Body`` > ``Bone`` with ``X``/``Y``/``Z`` children).
    Virtual points (``Virtual`` not 0) carry no marker and are skipped.
    """
    root = _parse_xml(path)
    out: dict[str, np.ndarray] = {}
    for b in root.iter("Body"):
        name = (b.findtext("Name") or "").strip() or f"body{len(out) + 1}"
        pts = []
        points = list(b.iter("Point"))
        for p in points:
            if p.attrib.get("Virtual", "0").strip().lower() not in ("0", "false", ""):
                continue
            if "X" in p.attrib:
                pts.append([_num(path, f"{name} point {c}", p.attrib.get(c)) for c in "XYZ"])
            else:
                pts.append([_num(path, f"{name} point {c}", p.findtext(c)) for c in "XYZ"])
        if not points:
            for bone in b.findall("Bone"):
                pts.append([_num(path, f"{name} bone {c}", bone.findtext(c)) for c in "XYZ"])
        if name in out:
            raise StarforgeError(f"{path}: two bodies are named {name!r}")
        out[name] = np.array(pts, dtype=float).reshape(-1, 3)
    if not out:
        raise StarforgeError(f"{path} holds no QTM Body (expected The_6D > Body > Points > Point)")
    return out


def read_vsk(path) -> dict[str, np.ndarray]:
    """Rigid bodies of a Vicon VSK: {name: (n, 3) mm}, one per segment that carries markers.

    A marker's ``POSITION`` is in its ``SEGMENT``'s frame, so each segment is one rigid body
    (an object VSK has one segment; a skeleton VSK has one per limb).  Position tokens are
    numbers or parameter names (``Parameters`` > ``Parameter NAME= VALUE=``), a leading ``-``
    negating a parameter, as Vicon writes ``-HipWidth``.  Bodies are named after the marker set
    when it has one segment, ``<marker set>_<segment>`` otherwise.
    """
    root = _parse_xml(path)
    if root.tag != "KinematicModel":
        raise StarforgeError(f"{path}: a VSK's root is KinematicModel, not {root.tag!r}")
    params: dict[str, float] = {}
    for p in root.iter("Parameter"):
        if "NAME" in p.attrib:
            value = p.attrib.get("VALUE", p.attrib.get("PRIOR"))
            params[p.attrib["NAME"]] = _num(path, f"parameter {p.attrib['NAME']}", value)

    def value(tok: str, marker: str) -> float:
        if tok in params:
            return params[tok]
        if tok.startswith("-") and tok[1:] in params:
            return -params[tok[1:]]
        return _num(path, f"marker {marker} POSITION token", tok)

    out: dict[str, np.ndarray] = {}
    for ms in root.iter("MarkerSet"):
        set_name = ms.attrib.get("NAME") or Path(path).stem
        groups: dict[str, list] = {}
        for m in ms.iter("Marker"):
            name = m.attrib.get("NAME", "?")
            toks = m.attrib.get("POSITION", "").split()
            if len(toks) != 3:
                raise StarforgeError(f"{path}: marker {name} needs a POSITION of 3 values, got {len(toks)}")
            groups.setdefault(m.attrib.get("SEGMENT", ""), []).append([value(t, name) for t in toks])
        for seg, pts in groups.items():
            key = set_name if len(groups) == 1 or not seg else f"{set_name}_{seg}"
            if key in out:
                raise StarforgeError(f"{path}: two rigid bodies are named {key!r}")
            out[key] = np.array(pts, dtype=float).reshape(-1, 3)
    if not out:
        raise StarforgeError(f"{path} holds no VSK marker (expected MarkerSet > Markers > Marker)")
    return out


def read_atracsys(path) -> dict[str, np.ndarray]:
    """An Atracsys geometry ``.ini``: {file stem: (count, 3) mm}.  Optional sections such as
    ``[pivot]`` are ignored."""
    _check_size(path)
    cp = configparser.ConfigParser()
    try:
        cp.read_string(Path(path).read_text(encoding="utf-8"))
        n = cp.getint("geometry", "count")
        cp.getint("geometry", "id")
        if not 3 <= n <= 64:
            raise ValueError(f"count {n} is outside 3..64")
        pts = [[cp.getfloat(f"fiducial{i}", c) for c in "xyz"] for i in range(n)]
    except (configparser.Error, ValueError, UnicodeDecodeError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else ""
        raise StarforgeError(
            f"{path} is not an Atracsys geometry file ({exc.__class__.__name__}: {msg})"
        ) from None
    P = np.array(pts, dtype=float).reshape(-1, 3)
    if not np.isfinite(P).all():
        raise StarforgeError(f"{path}: fiducial coordinates must be finite numbers")
    return {Path(path).stem: P}


#: body CSV coordinate columns and the factor to mm
_CSV_UNITS = {("x_mm", "y_mm", "z_mm"): 1.0, ("x_m", "y_m", "z_m"): 1000.0}


def read_csv(path) -> dict[str, np.ndarray]:
    """``body,marker,x_mm,y_mm,z_mm`` rows (or ``x_m,y_m,z_m``, converted): {body: (n, 3) mm},
    each body's markers in marker order."""
    _check_size(path)
    rows: dict[str, list] = {}
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = tuple(reader.fieldnames or ())
            cols = next((c for c in _CSV_UNITS if set(c) <= set(header)), None)
            if cols is None or not {"body", "marker"} <= set(header):
                raise KeyError(f"header {','.join(header)}")
            for r in reader:
                rows.setdefault(r["body"], []).append(
                    (
                        int(r["marker"]),
                        [_num(path, f"{r['body']} {c}", r[c]) * _CSV_UNITS[cols] for c in cols],
                    )
                )
    except (KeyError, ValueError, TypeError, UnicodeDecodeError, csv.Error) as exc:
        raise StarforgeError(
            f"{path} is not a body,marker,x_mm,y_mm,z_mm table ({exc.__class__.__name__}: {exc})"
        ) from None
    if not rows:
        raise StarforgeError(f"{path} holds no body rows")
    out = {}
    for k, v in rows.items():
        ids = [i for i, _ in v]
        if len(set(ids)) != len(ids):
            raise StarforgeError(f"{path}: body {k} numbers a marker twice")
        out[k] = np.array([p for _, p in sorted(v)], dtype=float).reshape(-1, 3)
    return out


def sniff_format(path) -> str | None:
    """The tracker format of a file by its content (then its suffix), or None."""
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(4096)
    head = head.removeprefix(b"\xef\xbb\xbf").lstrip()
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
    return {".ini": "atracsys", ".vsk": "vsk", ".csv": "csv"}.get(path.suffix.lower())


READERS = {"qtm": read_qtm, "vsk": read_vsk, "atracsys": read_atracsys, "csv": read_csv}
