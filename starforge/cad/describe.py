"""The printable bodies of a family from a mount's and the body's options, checked before any
file is written; and the ``starforge stars`` command that makes a family for another mount.
"""

from __future__ import annotations

from starforge.cad.body import BodySpec, seat_kind
from starforge.cad.export import check_fit, family_bodies, parse_ids
from starforge.cad.mounts import load_mount
from starforge.catalog import load_template
from starforge.errors import StarforgeError
from starforge.markers import CLEARANCE_HOLES_MM, metric_size
from starforge.spec import from_mapping
from starforge.stars.spec import spec_from_mapping


def parse_sets(items, mount_name: str) -> dict:
    """``["hole_mm=M3", "holes=2"]`` -> {"hole_mm": 3.2, "holes": 2.0}: numbers, and a metric screw
    size for a hole (its ISO 273 clearance hole); the keys are checked against ``mount_name``'s
    parameters first, so a wrong key is named as such."""
    out: dict = {}
    known = None
    for item in items or []:
        key, sep, val = (x.strip() for x in str(item).partition("="))
        if not sep or not key:
            raise StarforgeError(f"--set takes KEY=VALUE (a mount parameter), e.g. --set holes=2; got {item!r}")
        known = known or load_mount(mount_name).params
        if key not in known:
            raise StarforgeError(
                f"--set {key}: mount {mount_name} has no parameter {key}; its parameters: {', '.join(known)} "
                f"(see `starforge mounts {mount_name}`)"
            )
        size = metric_size(val) if key.endswith("hole_mm") else None
        if size is not None:
            out[key] = CLEARANCE_HOLES_MM[size]
            continue
        try:
            out[key] = float(val)
        except ValueError:
            hint = f" or a metric screw size such as M3 ({', '.join(CLEARANCE_HOLES_MM)})" if key.endswith("hole_mm") else ""
            raise StarforgeError(f"--set {key} needs a number in mm{hint}; got {val!r}") from None
    return out


def body_spec_from_options(**kw):
    """A validated BodySpec from CLI options (None = the default)."""
    return from_mapping(BodySpec, {k: v for k, v in kw.items() if v is not None}, where="body options")


def describe_bodies(family, mount, sets, ids, allow_oversize, **body_options):
    """The CAD options of ``export`` and ``preview`` -> (mount, body spec, id list, bodies).
    Every check that can fail runs here, before any file is written: the mount and its
    parameters, the body options (stems thinner than printable, ...), the ids, and the fit of
    every body against the family's size limit (unless ``allow_oversize``).
    """
    name = mount or family.spec.mount or "flat"
    overrides = parse_sets(sets, name)
    try:
        m = load_mount(name, overrides)
    except StarforgeError as exc:  # a value --set gave out of its range: name the option
        key = str(exc).split(" ", 1)[0]
        if key not in overrides:
            raise
        raise StarforgeError(f"--set {exc} (see `starforge mounts {name}`)") from None
    # the marker and seat the family was designed for, unless told otherwise
    if body_options.get("marker") is None and getattr(family.spec, "marker", None) is not None:
        body_options["marker"] = family.spec.marker
        if body_options.get("seat") is None:
            body_options["seat"] = family.spec.seat
    elif body_options.get("seat") is None and body_options.get("marker") is None:
        body_options["seat"] = getattr(family.spec, "seat", None)
    spec = body_spec_from_options(**body_options)

    try:
        seat_kind(spec, family.spec.marker_mm)  # the seat suits the marker, before any star is built
    except StarforgeError as exc:
        if spec.marker is None or spec.marker == family.spec.marker:
            raise
        # another bought marker than the family's: a family designed for it is the way out
        command = stars_command_for(family.spec, m.name, spec.marker, spec.seat)
        raise StarforgeError(f"{exc}; make a family for it: {command}") from None
    id_list = parse_ids(ids)
    bodies = family_bodies(family, id_list, m, spec)
    try:
        check_fit(bodies, family.spec.box_mm, m.name, allow_oversize)
    except StarforgeError as exc:
        if family.spec.mount == m.name or sets:  # made for this mount already: the command would not help
            raise
        raise StarforgeError(
            f"{exc}; or make a family for this mount: "
            f"{stars_command_for(family.spec, m.name, body_options.get('marker'), body_options.get('seat'))}"
        ) from None
    return m, spec, id_list, bodies


#: the ``starforge stars`` option of each spec field a family records
_STARS_FLAGS = (
    ("box_mm", "--box"),
    ("marker_mm", "--marker"),
    ("delta_mm", "--delta"),
    ("gap_mm", "--gap"),
    ("rule", "--rule"),
    ("select", "--select"),
    ("tolerance_mm", "--tolerance"),
    ("box_method", "--box-method"),
    ("min_depth_mm", "--min-depth"),
    ("tip_mm", "--tip"),
    ("noise_mm", "--noise"),
    ("count", "--count"),
)


def stars_command_for(spec, mount_name: str, marker: str | None = None, seat: str | None = None) -> str:
    """The ``starforge stars`` command that makes ``spec``'s family again, for ``mount_name``: the
    options where the spec differs from the default (the finger template), a new name; the bought
    ``marker`` (a catalogue name, else the family's) and ``seat`` the bodies are made with."""
    base = spec_from_mapping(load_template("stars", "finger")[1], name="finger")

    def word(v) -> str:
        if isinstance(v, (tuple, list)):
            return " ".join(word(x) for x in v)
        return f"{v:g}" if isinstance(v, float) else str(v)

    parts = ["starforge stars"]
    marker = marker or spec.marker
    for field, flag in _STARS_FLAGS:
        v = getattr(spec, field)
        if field == "marker_mm" and marker is not None:
            parts.append(f"--marker {marker}")
        elif v is not None and v != getattr(base, field):
            parts.append(f"{flag} {word(v)}")
    parts += [f"--name {spec.name}-{mount_name}", f"--mount {mount_name}"]
    if seat or spec.seat:
        parts.append(f"--seat {seat or spec.seat}")
    return " ".join(parts)
