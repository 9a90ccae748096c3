"""Exact B-rep bodies on build123d: a :class:`~starforge.cad.body.Body` -> one valid solid, STEP files.

build123d's direct API builds everything (no builder contexts): each primitive is a
``Solid.make_sphere`` / ``make_box`` / ``make_cylinder`` / ``revolve`` / ``extrude`` placed by a
``Plane``; the body is ``fuse`` of the added primitives, ``cut`` by the subtracted ones, merged
coplanar faces (``clean``), checked with ``is_valid`` and required to be a single solid.  A
solid carries its STEP name and colour (``label``, ``color``); a plate is a ``Compound`` whose
children are its bodies' solids, each ``moved`` to its place on the bed; ``export_step`` writes
both, ``import_step`` reads them back.

OCP (the OpenCascade bindings under build123d) is called where build123d has no call:
:func:`placed` bakes a rigid transform into a copy of the geometry, and :func:`write_step` puts
the colour styles in a fixed order between the STEP writer's transfer and its write.

build123d loads in :func:`kernel` only, the modules the bodies use: its import takes seconds, so
``import starforge`` and the commands that build no solid stay fast.
"""

from __future__ import annotations

import copy
import importlib
import importlib.util
import sys
import types

import numpy as np

from starforge.cad.body import Body
from starforge.cad.primitives import Box, Cylinder, Revolved, Sphere, merge_coaxial, plate_cuts
from starforge.errors import StarforgeError
from starforge.geometry.frames import perpendicular_basis
from starforge.geometry.outline import rect_union_outlines

#: the header's time stamp: fixed, so the same solid gives the same file
STEP_TIMESTAMP = "2000-01-01T00:00:00"
#: write each face's parameter-space curves too?  They repeat what the 3D edges and surfaces
#: already define, and readers rebuild them (OCCT does on import); without them a body's file
#: is less than half the size and quicker to write
STEP_PCURVES = False
#: the printing rotation :func:`placed` takes: +90 deg about x (:func:`starforge.cad.plate.print_transform`)
PRINT_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


#: the build123d modules the bodies use; its package's ``__init__`` imports every builder,
#: importer and exporter too (scikit-learn, ezdxf, SVG and font readers), which a STEP worker
#: would wait for (``benchmarks/bench_cad.py --speed-only`` prints both imports' CPU seconds)
KERNEL_MODULES = ("build123d.build_enums", "build123d.geometry", "build123d.topology", "build123d.exporters3d")
#: modules that :data:`KERNEL_MODULES` import at their top for calls the bodies never make: a
#: curve optimiser and convex hulls (scipy), a pretty-printer for notebooks (IPython), glTF
#: materials and a web upload (threejs_materials, requests).  While the kernel loads, each is a
#: :class:`_Deferred` module: a name taken from it imports the real module at its first use
DEFERRED_MODULES = ("scipy.optimize", "scipy.spatial", "IPython.lib.pretty", "threejs_materials", "requests")
_kernel = None


def kernel():
    """build123d's direct API: a namespace of the modules in :data:`KERNEL_MODULES` (imported
    on the first call), or the package itself once something has imported it whole."""
    global _kernel
    if _kernel is None:
        if "build123d" in sys.modules:
            return sys.modules["build123d"]
        mods = _import_modules(KERNEL_MODULES)
        _kernel = types.SimpleNamespace(**{k: v for m in mods for k, v in vars(m).items() if not k.startswith("_")})
    return _kernel


class _Deferred(types.ModuleType):
    """Stands in for a module while the kernel loads: ``from name import x`` binds a forwarder
    to ``name.x``, which imports the real module when it is called, read or checked against."""

    def __getattr__(self, attr: str):
        if attr.startswith("__"):
            raise AttributeError(attr)
        return _Forward(self.__name__, attr)


class _Forward:
    """``module.attr``, imported at its first use (a call, an attribute, an ``isinstance``)."""

    def __init__(self, module: str, attr: str) -> None:
        self._where = (module, attr)

    def _real(self):
        module, attr = self._where
        return getattr(importlib.import_module(module), attr)

    def __call__(self, *args, **kwargs):
        return self._real()(*args, **kwargs)

    def __getattr__(self, attr: str):
        if attr == "_where":
            raise AttributeError(attr)
        return getattr(self._real(), attr)

    def __instancecheck__(self, obj) -> bool:
        return isinstance(obj, self._real())


def _import_modules(names, defer: bool = True) -> list:
    """The build123d modules ``names``, imported without build123d's ``__init__`` (with
    ``defer``, the modules of :data:`DEFERRED_MODULES` not loaded yet deferred); the whole
    package if that fails (a build123d whose modules need its ``__init__``).

    Python runs a package's ``__init__`` before any of its modules; the modules are imported
    under a package object whose ``__init__`` has not run, which is then removed, so a later
    ``import build123d`` runs the real one, which finds these modules loaded and uses them (the
    classes are the same objects either way).
    """
    if "build123d" in sys.modules:
        return [importlib.import_module(m) for m in names]
    spec = importlib.util.find_spec("build123d")
    stand_ins = {m: _Deferred(m) for m in DEFERRED_MODULES if defer and m not in sys.modules}
    sys.modules.update(stand_ins)
    sys.modules["build123d"] = importlib.util.module_from_spec(spec)  # its __init__ not run
    try:
        mods = [importlib.import_module(m) for m in names]
    except (ImportError, AttributeError, TypeError):
        for m in [m for m in sys.modules if m == "build123d" or m.startswith("build123d.")]:
            del sys.modules[m]
        mods = None
    finally:
        for m in stand_ins:
            del sys.modules[m]
    if mods is None:
        return [importlib.import_module("build123d")]
    del sys.modules["build123d"]
    return mods


def _plane(origin, z=(0.0, 0.0, 1.0)):
    """A Plane at ``origin`` (3,) mm with its normal along ``z`` (3,) (its X chosen as OCCT's gp_Ax3 does)."""
    bd = kernel()
    return bd.Plane(origin=tuple(map(float, origin)), z_dir=tuple(map(float, z)))


def primitive_solid(p, axis=None):
    """One primitive as a build123d Solid, mm.

    ``axis`` (3,) orients a sphere's pole along a stem: the stem then meets the sphere on one of
    its parallels (an iso-parametric circle), which OCCT intersects several times faster than a
    circle across the sphere's parametrisation.  The solid is the same either way.
    """
    bd = kernel()
    if isinstance(p, Sphere):
        return bd.Solid.make_sphere(p.radius_mm, _plane(p.centre, (0.0, 0.0, 1.0) if axis is None else axis))
    if isinstance(p, Box):
        return bd.Solid.make_box(*p.size, _plane(np.subtract(p.centre, np.divide(p.size, 2))))
    if isinstance(p, Cylinder):
        return bd.Solid.make_cylinder(p.radius_mm, p.length_mm, _plane(p.p0, np.subtract(p.p1, p.p0)))
    if isinstance(p, Revolved):
        return _revolved_solid(p)
    raise TypeError(f"unknown primitive {type(p).__name__}")


def _revolved_solid(p: Revolved):
    """The profile polygon (axis, polyline, axis) in a plane through the axis, turned 360 deg."""
    bd = kernel()
    u = np.asarray(p.axis, float)
    w, _ = perpendicular_basis(u)
    o = np.array(p.p0)
    pts = [o + p.profile[0][0] * u, *(o + t * u + r * w for t, r in p.profile), o + p.profile[-1][0] * u]
    face = bd.Face(bd.Wire.make_polygon([tuple(map(float, q)) for q in pts]))
    return bd.Solid.revolve(face, 360, bd.Axis(tuple(map(float, o)), tuple(map(float, u))))


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
        rects = [(b[0, 0], b[1, 0], b[0, 2], b[1, 2]) for b in (x.bounds() for x in spans[key])]  # (x0, x1, z0, z1)
        for outer, holes in rect_union_outlines(rects):
            lo = np.array([outer[:, 0].min(), key[0], outer[:, 1].min()])
            hi = np.array([outer[:, 0].max(), key[1], outer[:, 1].max()])
            out.append((_prism(outer, holes, key[0], key[1] - key[0]), np.array([lo, hi])))
    return out


def _prism(outer, holes, y0: float, height: float):
    """The solid between y = ``y0`` and ``y0 + height`` over a polygon with holes, given as
    (k, 2) (x, z) corners (outer counter-clockwise in (x, z), holes clockwise)."""
    bd = kernel()

    def wire(loop):
        return bd.Wire.make_polygon([(float(x), float(y0), float(z)) for x, z in loop])

    return bd.Solid.extrude(bd.Face(wire(outer), [wire(h) for h in holes]), (0.0, float(height), 0.0))


def body_solid(body: Body):
    """The body as one valid build123d Solid, labelled ``body.name``.

    (union of ``add``) minus (union of ``subtract``), evaluated in the order that is fastest
    for OCCT and gives the same solid: a cut whose bounds meet only a plate's is made on that
    plate before the union ((A u B) - C = (A - C) u B when C misses B), and a vertical stem with
    its root fillet is one solid of revolution (:func:`~starforge.cad.primitives.merge_coaxial`),
    boxes cut over one height range (the id's pixel runs) one prism of their outline
    (:func:`cut_tools`).  The coplanar faces the booleans leave are merged once, at the end.
    """
    bd = kernel()
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
    with bd.SkipClean():  # one clean() below instead of one per boolean
        for i, tools in early.items():
            adds[i] = adds[i].cut(*tools)
        shape = adds[0].fuse(*adds[1:]) if len(adds) > 1 else adds[0]
        if late:
            shape = shape.cut(*late)
    solids = shape.clean().solids()
    if len(solids) != 1:
        raise StarforgeError(f"{body.name}: the STEP body has {len(solids)} solids, expected one")
    out = solids[0]
    if not out.is_valid:
        raise StarforgeError(f"{body.name}: OCCT's validity check failed for the solid")
    out.label = body.name
    return out


def _location(T):
    """The Location of a rigid (4, 4) transform, from its axes as given (no angles)."""
    bd = kernel()
    M = np.asarray(T, float)
    return bd.Location(bd.Plane(origin=tuple(M[:3, 3]), x_dir=tuple(M[:3, 0]), z_dir=tuple(M[:3, 2])))


def placed(solid, T, name: str, colour):
    """A copy of ``solid`` with its geometry moved by the rigid transform ``T`` (4, 4) (the
    printing rotation, +90 deg about x, plus a translation, as
    :func:`starforge.cad.plate.print_transform` makes), named and coloured ((r, g, b) 0..255)."""
    # OCP here: a STEP writer turns a solid with a location into an assembly of one part, so the
    # geometry itself moves; build123d's transform_shape keeps the geometry and sets a location,
    # and its rotate / translate (transform=True) take an angle, whose cosine is not 0 at 90 deg
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform

    bd = kernel()
    if not np.allclose(np.asarray(T, float)[:3, :3], PRINT_ROTATION):
        raise ValueError("placed() takes the printing rotation (+90 deg about x) only")
    trsf = _location(T).wrapped.Transformation()
    out = bd.Solid(BRepBuilderAPI_Transform(solid.wrapped, trsf, True).Shape())
    out.label = name
    out.color = bd.Color(*(int(c) / 255 for c in colour))
    return out


def assembly(solids, transforms, name: str):
    """A STEP assembly named ``name`` of named, coloured ``solids``, each moved by one of
    ``transforms`` (4, 4); the instances share their solid's geometry."""
    bd = kernel()
    parts = []
    for s, T in zip(solids, transforms, strict=True):
        part = copy.copy(s)  # build123d's shallow copy: another instance of the same geometry
        part.move(_location(T))
        parts.append(part)
    return bd.Compound(parts, label=name, children=parts)


def write_step(shape, path) -> None:
    """Write a named solid or an :func:`assembly` to a STEP file (AP214, mm, fixed header time
    stamp, the colour styles in a fixed order: :func:`_order_styles`).  The caller stages the
    path (atomic outputs)."""
    try:
        ok = _write_step(shape, str(path))
    except RuntimeError as exc:
        raise StarforgeError(f"could not write STEP file {path}: {exc}") from None
    if not ok:
        raise StarforgeError(f"could not write STEP file {path}")


def _write_step(shape, path: str) -> bool:
    """build123d's ``export_step`` (its XCAF document, header and writer settings), with
    :func:`_order_styles` between the transfer and the write."""
    # OCP here: build123d's export_step transfers and writes in one call, and the writer lists
    # the styles in an order that is not the same from process to process
    from OCP.APIHeaderSection import APIHeaderSection_MakeHeader
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.IGESControl import IGESControl_Controller
    from OCP.Interface import Interface_Static
    from OCP.Message import Message, Message_Gravity
    from OCP.STEPCAFControl import STEPCAFControl_Controller, STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_Controller, STEPControl_StepModelType
    from OCP.TCollection import TCollection_HAsciiString
    from OCP.XSControl import XSControl_WorkSession

    bd = kernel()
    (exporters,) = _import_modules(["build123d.exporters3d"])
    create = getattr(exporters, "_create_xde", None)
    if create is None:  # a build123d without it: its own export, the styles in the writer's order
        return bd.export_step(shape, path, bd.Unit.MM, write_pcurves=STEP_PCURVES, timestamp=STEP_TIMESTAMP)
    doc = create(shape, bd.Unit.MM, auto_naming=True)
    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)
    writer = STEPCAFControl_Writer(XSControl_WorkSession(), False)
    writer.SetColorMode(True)
    writer.SetLayerMode(True)
    writer.SetNameMode(True)
    model = writer.Writer().Model()
    header = APIHeaderSection_MakeHeader(model)
    if not header.IsDone():
        header = APIHeaderSection_MakeHeader(0)
        header.Apply(model)
    if shape.label:
        header.SetName(TCollection_HAsciiString(shape.label))
    header.SetTimeStamp(TCollection_HAsciiString(STEP_TIMESTAMP))
    header.SetOriginatingSystem(TCollection_HAsciiString("build123d"))
    STEPCAFControl_Controller.Init_s()
    STEPControl_Controller.Init_s()
    IGESControl_Controller.Init_s()
    Interface_Static.SetIVal_s("write.surfacecurve.mode", int(STEP_PCURVES))
    Interface_Static.SetIVal_s("write.precision.mode", bd.PrecisionMode.AVERAGE.value)
    writer.Transfer(doc, STEPControl_StepModelType.STEPControl_AsIs)
    _order_styles(writer.Writer().Model())
    return writer.Write(path) == IFSelect_ReturnStatus.IFSelect_RetDone


def _order_styles(model) -> None:
    """Put the colour styles of a transferred STEP ``model`` in a fixed order.

    OCCT's STEPCAFControl writer adds one presentation (MECHANICAL_DESIGN_GEOMETRIC_PRESENTATION_
    REPRESENTATION) per coloured part last, each with the styles and colours it refers to, in
    the order of a map hashed by the parts' addresses: an assembly of several coloured parts
    comes out in an order that changes from process to process.  The presentations' blocks are
    put in the order of their styled items' entity numbers (given before the styles, in the
    assembly's order), each block's entities kept in the order the writer added them and a
    colour entity that parts of one colour share put after the first entity that names it.  The
    entities move within the model; their numbers are given when the file is written, so every
    reference follows its entity.  A model of one presentation (a body's own file) is left as
    the writer made it.
    """
    from OCP.StepVisual import StepVisual_Colour as Colour
    from OCP.StepVisual import StepVisual_CurveStyle as Curve
    from OCP.StepVisual import StepVisual_FillAreaStyleColour as FillColour
    from OCP.StepVisual import StepVisual_MechanicalDesignGeometricPresentationRepresentation as Mdgpr

    # the model's entities and their numbers, by the wrappers OCP keeps one of per entity (its
    # Number() does not find an entity passed from Python)
    ents = [model.Value(i) for i in range(1, model.NbEntities() + 1)]
    number = {id(e): i for i, e in enumerate(ents, 1)}
    heads = [e for e in ents if isinstance(e, Mdgpr)]
    if len(heads) < 2:
        return
    start = min(number[id(h)] for h in heads)

    def key(h):
        items = h.Items()
        targets = [number[id(items.Value(j).Item())] for j in range(items.Lower(), items.Upper() + 1)]
        return (sorted(targets), number[id(h.ContextOfItems())])

    # the writer adds each presentation with the entities it refers to that the model does not
    # hold yet, the presentation first: a presentation's block runs up to the next one's.  Parts
    # of one colour share its colour entity, which sits in the block the writer added first: a
    # colour goes after the first entity that names it, in the blocks' new order
    at = sorted(number[id(h)] for h in heads) + [len(ents) + 1]
    blocks = {i: range(i, j) for i, j in zip(at[:-1], at[1:], strict=True)}
    order, placed = [], set()
    for h in sorted(heads, key=key):
        for i in blocks[number[id(h)]]:
            e = ents[i - 1]
            if isinstance(e, Colour):
                continue
            order.append(e)
            named = [e.FillColour()] if isinstance(e, FillColour) else [e.CurveColour()] if isinstance(e, Curve) else []
            for c in named:
                n = number.get(id(c), 0)
                if n >= start and n not in placed:
                    placed.add(n)
                    order.append(c)
    order += [e for e in ents[start - 1 :] if isinstance(e, Colour) and number[id(e)] not in placed]
    _permute_tail(model, start, [number[id(e)] for e in ents[start - 1 :]], [number[id(e)] for e in order])
    if [id(model.Value(i)) for i in range(start, len(ents) + 1)] != [id(e) for e in order]:
        raise RuntimeError("the styles could not be put in order")


def _permute_tail(model, start: int, cur: list, want: list) -> None:
    """Reorder the entities from number ``start`` on, now ``cur`` (their labels, in order), into
    ``want`` (the same labels) by reversing the model's tail (its one reordering that takes no
    entity from Python): each run of ``want`` found together in ``cur`` moves in at most three
    reversals."""
    cur = list(cur)

    def flip(at: int) -> None:  # reverse the entities after the first start + at - 1
        model.ReverseOrders(start + at - 1)
        cur[at:] = cur[at:][::-1]

    p = 0
    while p < len(want):
        q = cur.index(want[p])
        k = 1  # the run want[p : p + k] is at cur[q : q + k] (forward) or cur[q - k + 1 : q + 1] (reversed)
        if q + 1 < len(cur) and p + 1 < len(want) and cur[q + 1] == want[p + 1]:
            while p + k < len(want) and q + k < len(cur) and cur[q + k] == want[p + k]:
                k += 1
            forward, lo = True, q
        else:
            while p + k < len(want) and q - k >= p and cur[q - k] == want[p + k]:
                k += 1
            forward, lo = k == 1, q - k + 1
        if lo == p and forward:
            p += k
            continue
        flip(lo)  # the run at the end, its order reversed
        if not forward:
            flip(len(cur) - k)  # the run on its own: forward again
        flip(p)  # the run at p, forward
        p += k


def read_step(path) -> list:
    """The solids of a STEP file (build123d Solids)."""
    kernel()
    (importers,) = _import_modules(["build123d.importers"], defer=False)
    return importers.import_step(str(path)).solids()
