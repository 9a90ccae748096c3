"""OpenCascade backend: a :class:`~starforge.cad.body.Body` -> one exact B-rep solid, STEP files.

Straight on OCP (the OpenCascade bindings build123d is built on), not through build123d: the
STEP worker (:mod:`starforge.cad.step_worker`) would wait for ``import build123d``, whose package
also imports all its importers and exporters, scikit-learn and IPython, several times what
these OCP modules take (``benchmarks/bench_cad.py --speed-only`` prints both as
``kernel_import_cpu_s``); build123d keeps those imports eager by choice (gumyr/build123d pull
request 942, declined).  Every primitive is an OCCT solid; the body is the fuse of the added
primitives, cut by the subtracted ones, checked with OCCT's validity check and required to be a
single solid.  STEP files are written through an XCAF document, so each solid carries its name
(the STEP product) and colour; a plate is an assembly of such solids.  build123d (or any STEP
reader) reads them back; the tests do.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from starforge.cad.body import Body
from starforge.cad.primitives import Box, Cylinder, Revolved, Sphere, merge_coaxial, plate_cuts
from starforge.errors import StarforgeError

#: the header's time stamp: fixed, so the same solid gives the same file
STEP_TIMESTAMP = "2000-01-01T00:00:00"
#: write each face's parameter-space curves too (OCCT's write.surfacecurve.mode)?  They repeat
#: what the 3D edges and surfaces already define, and readers rebuild them (OCCT does on import);
#: without them a body's file is less than half the size and quicker to write
STEP_PCURVES = False


@dataclass(frozen=True)
class Solid:
    """An OCCT solid with the name and colour its STEP file gives it.

    Attributes
    ----------
    shape : OCP TopoDS_Shape (a solid), mm
    label : str, the STEP product name ("" for none)
    colour : (r, g, b) 0..255 or None
    """

    shape: object
    label: str = ""
    colour: tuple | None = None

    @property
    def volume(self) -> float:
        """mm^3, OCCT's exact volume integral."""
        from OCP.BRepGProp import BRepGProp
        from OCP.GProp import GProp_GProps

        props = GProp_GProps()
        BRepGProp.VolumeProperties_s(self.shape, props)
        return float(props.Mass())

    @property
    def is_valid(self) -> bool:
        """OCCT's validity check (BRepCheck_Analyzer)."""
        from OCP.BRepCheck import BRepCheck_Analyzer

        return bool(BRepCheck_Analyzer(self.shape).IsValid())


def _pnt(p):
    from OCP.gp import gp_Pnt

    return gp_Pnt(*(float(x) for x in p))


def _ax2(origin, z=(0.0, 0.0, 1.0)):
    """A placement at ``origin`` with its Z along ``z`` (X chosen by OCCT, as gp_Ax3 does)."""
    from OCP.gp import gp_Ax2, gp_Dir

    z = np.asarray(z, float)
    z = z / np.linalg.norm(z)
    return gp_Ax2(_pnt(origin), gp_Dir(*(float(v) for v in z)))


def primitive_solid(p, axis=None):
    """One primitive as an OCCT solid (TopoDS_Shape).

    ``axis`` (3,) orients a sphere's pole along a stem: the stem then meets the sphere on one of
    its parallels (an iso-parametric circle), which OCCT intersects several times faster than a
    circle across the sphere's parametrisation.  The solid is the same either way.
    """
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox, BRepPrimAPI_MakeCylinder, BRepPrimAPI_MakeSphere

    if isinstance(p, Sphere):
        ax = _ax2(p.centre, (0.0, 0.0, 1.0) if axis is None else axis)
        return BRepPrimAPI_MakeSphere(ax, float(p.radius_mm), -np.pi / 2, np.pi / 2, 2 * np.pi).Shape()
    if isinstance(p, Box):
        sx, sy, sz = (float(v) for v in p.size)
        c = np.array(p.centre) - np.array(p.size) / 2
        return BRepPrimAPI_MakeBox(_ax2(c), sx, sy, sz).Shape()
    if isinstance(p, Cylinder):
        p0, p1 = np.array(p.p0), np.array(p.p1)
        h = float(np.linalg.norm(p1 - p0))
        return BRepPrimAPI_MakeCylinder(_ax2(p0, (p1 - p0) / h), float(p.radius_mm), h, 2 * np.pi).Shape()
    if isinstance(p, Revolved):
        return _revolved_solid(p)
    raise TypeError(f"unknown primitive {type(p).__name__}")


def _revolved_solid(p: Revolved):
    """The profile polygon (axis, polyline, axis) in a plane through the axis, turned 360 deg."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeRevol
    from OCP.gp import gp_Ax1, gp_Dir

    u = p.axis
    helper = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    w = np.cross(u, helper)
    w /= np.linalg.norm(w)
    o = np.array(p.p0)
    pts = [o + p.profile[0][0] * u, *(o + t * u + r * w for t, r in p.profile), o + p.profile[-1][0] * u]
    poly = BRepBuilderAPI_MakePolygon()
    for q in pts:
        poly.Add(_pnt(q))
    poly.Close()
    face = BRepBuilderAPI_MakeFace(poly.Wire(), True).Face()
    return BRepPrimAPI_MakeRevol(face, gp_Ax1(_pnt(o), gp_Dir(*map(float, u))), 2 * np.pi).Shape()


def _sphere_axes(body: Body, parts) -> dict:
    """{index in ``parts`` of a sphere: its stem's direction} (stems end at their sphere's centre)."""
    out = {}
    ends = {tuple(np.round(s.p1, 9)): np.subtract(s.p1, s.p0) for s in body.stems}
    for i, p in enumerate(parts):
        if isinstance(p, Sphere):
            u = ends.get(tuple(np.round(p.centre, 9)))
            if u is not None:
                out[i] = u
    return out


def cut_tools(subtract) -> list:
    """(solid, (2, 3) bounds) per cut: boxes that span the same height (y) range, such as an
    engraved id's pixel runs, as one prism of their outline (the same solid: a union of boxes
    over one y range is the union of their rectangles, extruded), the rest one by one."""
    from starforge.geometry.outline import rect_union_outlines

    spans: dict = {}
    for c in subtract:
        if isinstance(c, Box):
            b = c.bounds()
            spans.setdefault((b[0, 1], b[1, 1]), []).append(c)
    out, done = [], set()
    for c in subtract:
        key = (c.bounds()[0, 1], c.bounds()[1, 1]) if isinstance(c, Box) else None
        if key is None or len(spans[key]) < 2:
            out.append((primitive_solid(c), c.bounds()))
            continue
        if key in done:
            continue
        done.add(key)
        boxes = [b.bounds() for b in spans[key]]
        rects = [(b[0, 0], b[1, 0], b[0, 2], b[1, 2]) for b in boxes]  # (x0, x1, z0, z1)
        for outer, holes in rect_union_outlines(rects):
            pts = outer[:, 0], outer[:, 1]
            lo = np.array([pts[0].min(), key[0], pts[1].min()])
            hi = np.array([pts[0].max(), key[1], pts[1].max()])
            out.append((_prism(outer, holes, key[0], key[1] - key[0]), np.array([lo, hi])))
    return out


def _prism(outer, holes, y0: float, height: float):
    """The solid between y = ``y0`` and ``y0 + height`` over a polygon with holes, given as
    (k, 2) (x, z) corners (outer counter-clockwise in (x, z), holes clockwise)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.BRepPrimAPI import BRepPrimAPI_MakePrism
    from OCP.gp import gp_Vec

    def wire(loop):
        poly = BRepBuilderAPI_MakePolygon()
        for x, z in loop:
            poly.Add(_pnt((x, y0, z)))
        poly.Close()
        return poly.Wire()

    make = BRepBuilderAPI_MakeFace(wire(outer), True)
    for h in holes:
        make.Add(wire(h))
    return BRepPrimAPI_MakePrism(make.Face(), gp_Vec(0.0, float(height), 0.0)).Shape()


def _shape_list(shapes):
    try:
        from OCP.collections import List_TopoDS_Shape as ShapeList  # OCP >= 7.8
    except ImportError:  # pragma: no cover - older OCP
        from OCP.TopTools import TopTools_ListOfShape as ShapeList
    out = ShapeList()
    for s in shapes:
        out.Append(s)
    return out


def _boolean(kind: str, args, tools):
    """OCCT's general fuse / cut of ``args`` with ``tools`` (lists of shapes), one call."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse

    op = BRepAlgoAPI_Fuse() if kind == "fuse" else BRepAlgoAPI_Cut()
    op.SetArguments(_shape_list(args))
    op.SetTools(_shape_list(tools))
    op.SetRunParallel(False)  # one core each: the export meshes on the other
    op.Build()
    if not op.IsDone():
        raise StarforgeError(f"OCCT boolean {kind} failed")
    return op.Shape()


def _solids(shape) -> list:
    from OCP.TopAbs import TopAbs_SOLID
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    cast = getattr(TopoDS, "Solid_s", None) or TopoDS.Solid  # OCP < 7.8 names statics *_s
    out = []
    ex = TopExp_Explorer(shape, TopAbs_SOLID)
    while ex.More():
        out.append(cast(ex.Current()))
        ex.Next()
    return out


def body_solid(body: Body) -> Solid:
    """The body as one valid OCCT solid, labelled ``body.name``.

    (union of ``add``) minus (union of ``subtract``), evaluated in the order that is fastest
    for OCCT and gives the same solid: a cut whose bounds meet only a plate's is made on that
    plate before the union ((A u B) - C = (A - C) u B when C misses B), and a vertical stem with
    its root fillet is one solid of revolution (:func:`~starforge.cad.primitives.merge_coaxial`),
    boxes cut over one height range (the id's pixel runs) one prism of their outline (:func:`cut_tools`).
    Coplanar faces left by the booleans are merged (ShapeUpgrade_UnifySameDomain).
    """
    from OCP.ShapeUpgrade import ShapeUpgrade_UnifySameDomain

    parts = merge_coaxial(body.add)
    axes = _sphere_axes(body, parts)
    adds = [primitive_solid(p, axes.get(i)) for i, p in enumerate(parts)]
    cuts = cut_tools(body.subtract)
    early: dict[int, list] = {}
    late = []
    for (solid, _), plate in zip(cuts, plate_cuts(parts, [cb for _, cb in cuts]), strict=True):
        if plate is None:
            late.append(solid)
        else:
            early.setdefault(plate, []).append(solid)
    for i, tools in early.items():
        adds[i] = _boolean("cut", [adds[i]], tools)
    shape = _boolean("fuse", adds[:1], adds[1:]) if len(adds) > 1 else adds[0]
    if late:
        shape = _boolean("cut", [shape], late)
    unify = ShapeUpgrade_UnifySameDomain(shape, True, True, True)
    unify.AllowInternalEdges(False)
    unify.Build()
    solids = _solids(unify.Shape())
    if len(solids) != 1:
        raise StarforgeError(f"{body.name}: the STEP body has {len(solids)} solids, expected one")
    out = Solid(solids[0], body.name)
    if not out.is_valid:
        raise StarforgeError(f"{body.name}: OCCT's validity check failed for the solid")
    return out


def _trsf(T):
    """gp_Trsf of a rigid (4, 4) transform, its matrix entries as given (no trigonometry)."""
    from OCP.gp import gp_Trsf

    M = np.asarray(T, float)
    t = gp_Trsf()
    t.SetValues(*(float(M[i, j]) for i in range(3) for j in range(4)))
    return t


def placed(solid: Solid, T, name: str, colour) -> Solid:
    """``solid`` moved by the rigid transform ``T`` (4, 4) (the printing rotation, +90 deg about
    x, plus a translation, as :func:`starforge.cad.plate.print_transform` makes), named and
    coloured ((r, g, b) 0..255).  The geometry itself moves (a copy), not a location: a STEP
    writer turns a located solid into an assembly of one part."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform

    R = np.asarray(T, float)[:3, :3]
    if not np.allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]]):
        raise ValueError("placed() takes the printing rotation (+90 deg about x) only")
    shape = BRepBuilderAPI_Transform(solid.shape, _trsf(T), True).Shape()
    return Solid(shape, name, tuple(int(c) for c in colour))


@dataclass(frozen=True)
class Assembly:
    """Named, coloured solids, each placed by a rigid (4, 4) transform: one STEP assembly."""

    solids: tuple
    transforms: tuple
    label: str


def assembly(solids, transforms, name: str) -> Assembly:
    """A STEP assembly of named, coloured ``solids``, instances moved by ``transforms`` (4, 4)."""
    return Assembly(tuple(solids), tuple(np.asarray(T, float) for T in transforms), name)


def _xcaf(item):
    """An XCAF document holding a Solid (one named, coloured shape) or an Assembly (a named
    assembly whose components refer to the named, coloured solids, placed by a location)."""
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFApp import XCAFApp_Application
    from OCP.XCAFDoc import XCAFDoc_ColorType, XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("XmlOcaf"))
    app = XCAFApp_Application.GetApplication_s()
    app.NewDocument(TCollection_ExtendedString("MDTV-XCAF"), doc)
    app.InitDocument(doc)
    XCAFDoc_DocumentTool.SetLengthUnit_s(doc, 0.001)  # mm
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    colours = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    shapes.SetAutoNaming_s(False)

    def name_and_colour(label, s: Solid) -> None:
        if s.label:
            TDataStd_Name.Set_s(label, TCollection_ExtendedString(s.label))
        if s.colour is not None:
            from OCP.Quantity import Quantity_Color, Quantity_TypeOfColor

            r, g, b = (c / 255 for c in s.colour)
            colours.SetColor(label, Quantity_Color(r, g, b, Quantity_TypeOfColor.Quantity_TOC_sRGB),
                             XCAFDoc_ColorType.XCAFDoc_ColorGen)

    if isinstance(item, Solid):
        name_and_colour(shapes.AddShape(item.shape, False), item)
    else:
        top = shapes.NewShape()
        TDataStd_Name.Set_s(top, TCollection_ExtendedString(item.label))
        for s, T in zip(item.solids, item.transforms, strict=True):
            part = shapes.AddShape(s.shape, False)
            name_and_colour(part, s)
            comp = shapes.AddComponent(top, part, TopLoc_Location(_trsf(T)))
            # the instance carries the name only: a colour there too becomes an overriding style,
            # which OCCT writes in an order that changes from run to run
            name_and_colour(comp, Solid(s.shape, s.label, None))
        shapes.UpdateAssemblies()
    return doc


def write_step(item, path) -> None:
    """Write a :class:`Solid` or an :class:`Assembly` to a STEP file (AP214, mm, fixed header
    time stamp).  The caller stages the path (atomic outputs)."""
    from OCP.APIHeaderSection import APIHeaderSection_MakeHeader
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.Interface import Interface_Static
    from OCP.Message import Message, Message_Gravity
    from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_Controller, STEPControl_StepModelType
    from OCP.TCollection import TCollection_HAsciiString
    from OCP.XSControl import XSControl_WorkSession

    doc = _xcaf(item)
    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)
    STEPCAFControl_Controller.Init_s()
    STEPControl_Controller.Init_s()
    writer = STEPCAFControl_Writer(XSControl_WorkSession(), False)
    writer.SetColorMode(True)
    writer.SetLayerMode(True)
    writer.SetNameMode(True)
    header = APIHeaderSection_MakeHeader(writer.Writer().Model())
    if not header.IsDone():
        header = APIHeaderSection_MakeHeader(0)
        header.Apply(writer.Writer().Model())
    header.SetName(TCollection_HAsciiString(item.label))
    header.SetTimeStamp(TCollection_HAsciiString(STEP_TIMESTAMP))
    header.SetOriginatingSystem(TCollection_HAsciiString("starforge"))
    Interface_Static.SetIVal_s("write.surfacecurve.mode", int(STEP_PCURVES))
    Interface_Static.SetIVal_s("write.precision.mode", 0)
    writer.Transfer(doc, STEPControl_StepModelType.STEPControl_AsIs)
    if writer.Write(str(path)) != IFSelect_ReturnStatus.IFSelect_RetDone:
        raise StarforgeError(f"could not write STEP file {path}")


def read_step(path):
    """The solids of a STEP file (list of build123d Solids; imports build123d: for checks)."""
    import build123d as bd

    return bd.import_step(str(path)).solids()
