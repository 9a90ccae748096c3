"""The help says what the code does: every option of every command, its default and its choices."""

from __future__ import annotations

import re

import pytest

from starforge.cli import click_command, main
from starforge.cli._args import normalise


@pytest.fixture(scope="module")
def root():
    return click_command()


def _walk(cmd, path):
    yield path, cmd
    for name, sub in getattr(cmd, "commands", {}).items():
        yield from _walk(sub, [*path, name])


def _options(root):
    for path, cmd in _walk(root, ["starforge"]):
        for p in cmd.params:
            if p.param_type_name == "option":
                yield " ".join(path), p


def _help(args, capsys) -> str:
    assert main([*args, "--help"]) == 0
    text = capsys.readouterr().out
    return " ".join(text.replace("│", " ").split())


#: options whose absence means "none of these" (no value is filled in for them)
_NOTHING_WHEN_ABSENT = {
    "--version",
    "--show",
    "--set",
    "--ids",
    "--rig",
    "--grip",
    "--json",
    "--tip",
    "--match",
    "--residual",
}


def test_every_option_says_what_it_is_when_not_given(root):
    """An option the code fills in when it is absent shows that default: click's own (shown by
    the help as [default: X]) or its help text says 'default'."""
    missing = []
    for where, p in _options(root):
        if p.is_flag or p.required or p.default not in (None, ()):
            continue
        if "default" in (p.help or "").lower() or p.opts[0] in _NOTHING_WHEN_ABSENT:
            continue
        missing.append(f"{where} {p.opts[0]}")
    assert not missing, missing


def test_every_option_is_in_its_commands_help(root, capsys):
    for path, cmd in _walk(root, ["starforge"]):
        if getattr(cmd, "commands", None) and path[-1] != "place":
            continue
        text = _help(path[1:], capsys)
        for p in cmd.params:
            if p.param_type_name == "option":
                assert p.opts[0] in text, (path, p.opts[0])
        assert "<bool>" not in text  # a flag takes no value


def test_place_help_shows_the_placement_options(capsys):
    text = _help(["place"], capsys)
    for flag in ("--sites", "--resolution", "--markers", "--marker", "--avoid", "place score"):
        assert flag in text


def _stated(help_text: str) -> str:
    """The value a help text states for the `default` template: "...; 600 in `default`" -> "600"."""
    m = re.search(r"; (\S+) in `default`", help_text)
    assert m, help_text
    return m.group(1)


def test_place_defaults_in_help_are_the_ones_the_spec_uses(root):
    from starforge.props.spec import load_spec

    s = load_spec("default")
    run = {p.opts[0]: p for p in root.commands["place"].commands["run"].params}
    used = {
        "--sites": s.sites,
        "--resolution": s.resolution,
        "--orientations": s.orientations,
        "--markers": s.track.target_markers,
        "--restarts": s.track.restarts,
        "--cameras-lost": s.track.cameras_lost,
        "--marker-mm": s.track.marker,
        "--rig": s.rig,
        "--mesh-format": s.mesh_format,
    }
    for flag, value in used.items():
        assert _stated(run[flag].help) == str(value), flag
    lo, hi = re.search(r"in \[(\d+), (\d+)\]", run["--markers"].help).groups()
    assert (int(lo), int(hi)) == (s.track.min_markers, s.track.max_markers)
    score = {p.opts[0]: p for p in root.commands["place"].commands["score"].params}
    assert _stated(score["--resolution"].help) == str(s.resolution)


def test_stars_defaults_and_choices_in_help_are_the_ones_used(root):
    from starforge.errors import StarforgeError
    from starforge.stars.spec import spec_from_mapping

    s = spec_from_mapping({"box_mm": [20.8, 12.6, 48.3]})
    opts = {p.opts[0]: p for p in root.commands["stars"].params}
    for flag, value, unit in (
        ("--delta", s.delta_mm, "mm"),
        ("--gap", s.gap_mm, "mm"),
        ("--marker", s.marker_mm, "mm"),
        ("--noise", s.noise_mm, "mm"),
    ):
        assert f"default {value:g} {unit}" in opts[flag].help, flag
    assert f"default {s.work}" in opts["--work"].help
    for flag, field in (("--rule", "rule"), ("--select", "select"), ("--box-method", "box_method")):
        assert f"default {getattr(s, field)}" in opts[flag].help
        listed = re.match(r"(\w+) or (\w+)", opts[flag].help).groups()
        for v in listed:  # every choice shown is accepted ...
            assert getattr(spec_from_mapping({"box_mm": [20.8, 12.6, 48.3], field: v}), field) == v
        with pytest.raises((StarforgeError, ValueError)):  # ... and one not shown is not
            spec_from_mapping({"box_mm": [20.8, 12.6, 48.3], field: "other"})


def test_other_help_texts_match_the_code(root):
    from starforge.api.bodies import default_out
    from starforge.catalog import KINDS
    from starforge.runtime import budget

    kind = next(p for p in root.commands["templates"].params if p.name == "kind")
    assert all(k in kind.help for k in KINDS)
    out = next(p for p in root.commands["export"].params if p.name == "out")
    assert "/bodies" in out.help and "/tracker" in out.help
    assert default_out(__import__("pathlib").Path("f/family.json"), False).name == "tracker"
    secs = next(p for p in root.params if p.name == "max_seconds")
    assert f"default {budget.DEFAULT_SECONDS:g}" in secs.help


@pytest.mark.parametrize(
    "given",
    [["20.8,12.6,48.3"], ["20.8", "12.6", "48.3"], ["20.8,", "12.6,48.3"], ["20.8", "12.6,48.3"]],
)
def test_three_numbers_comma_or_space(root, given):
    for flag, name in (("--box", "box"), ("--tip", "tip"), ("--reserve", "reserve")):
        args = normalise(root, ["stars", flag, *given, "--delta", "2"], {})
        ctx = root.commands["stars"].make_context("stars", args[1:])
        assert tuple(ctx.params[name]) == (20.8, 12.6, 48.3) and ctx.params["delta"] == 2.0


@pytest.mark.parametrize("given", [["25,15"], ["25", "15"], ["25", "15", "--delta", "1"], ["a,b,c"], []])
def test_three_numbers_refused_with_the_way_out(given, capsys):
    assert main(["stars", "--box", *given]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --box needs 3 values, e.g. --box 20.8,12.6,48.3") and err.count("\n") == 1


def test_global_options_after_the_command(root):
    meta: dict = {}
    args = normalise(
        root, ["check", "f.json", "--scheduler", "tcp://x:1", "--max-memory", "2G"], meta
    )
    assert args[:4] == ["--max-memory", "2G", "--scheduler", "tcp://x:1"] and args[4] == "check"
    # a command with an option of that name keeps it
    assert normalise(root, ["sweep", "--scheduler", "tcp://x:1"], {}) == ["sweep", "--scheduler", "tcp://x:1"]
    assert normalise(root, ["stars", "--scheduler", "tcp://x:1"], {}) == ["stars", "--scheduler", "tcp://x:1"]
    normalise(root, ["check", "f.json", "-q"], meta)
    assert meta.get("starforge.quiet")
    assert normalise(root, ["-q", "check", "f.json"], {})[-1] == "f.json"
    assert "-q" in normalise(root, ["-q", "check", "f.json"], {})[2:]  # the command's own -q too


def _default_clauses(help_text: str) -> list[str]:
    """What a help text says an option is when not given: each clause after the word "default"
    (not the template name `default`), up to a ';', a ')' or a full stop."""
    return re.findall(r"(?<![`\w])default:? (.*?)(?=;|\)|\.(?!\d)|$)", help_text or "", flags=re.I)


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"(?<![\w$<.-])-?\d+(?:\.\d+)?", text)]


def _body_spec():
    from starforge.cad.describe import body_spec_from_options

    return body_spec_from_options()


def _stars_spec():
    from starforge.stars.spec import spec_from_mapping

    return spec_from_mapping({"box_mm": [20.8, 12.6, 48.3]})


def _stem_rule() -> list[float]:
    """The stem's default as a rule: its factor on a marker large enough to be scaled, and its
    floor on one small enough to be held there."""
    spec = _body_spec()
    factor = spec.stem_for(5.0) / 5.0
    assert spec.stem_for(0.1) == spec.min_stem_mm
    return [factor, spec.min_stem_mm]


def _coating() -> list[float]:
    c, m = _body_spec().coating_mm, _stars_spec().marker_mm
    return [c, m - c, m]


def _tip() -> list[float]:
    from starforge.geometry.rigid import default_tip_mm

    tip = default_tip_mm([1.0, 2.0, 3.0])
    assert tip[2] == -3.0  # "-longest side"
    return [float(tip[0]), float(tip[1])]


def _memory_percent() -> list[float]:
    from starforge.runtime.budget import MEMORY_FRACTION

    return [100 * MEMORY_FRACTION]


def _seconds() -> list[float]:
    from starforge.runtime.budget import DEFAULT_SECONDS

    return [DEFAULT_SECONDS]


def _ambiguity() -> list[float]:
    from starforge.tracking.identify import AMBIGUITY

    return [AMBIGUITY]


def _placement_error() -> list[float]:
    from starforge.props.spec import load_spec

    return [load_spec("default").seat.placement_error_mm]


def _standoff() -> list[float]:
    from starforge.props.spec import load_spec

    return [load_spec("default").standoff_mm]


_BODY_NUMBERS = {
    "--nozzle-mm": lambda: [_body_spec().nozzle_mm],
    "--coating-mm": _coating,
    "--stem-mm": _stem_rule,
    "--min-stem-mm": lambda: [_body_spec().min_stem_mm],
    "--post-mm": lambda: [_body_spec().post_mm],
}

#: every number a help text states as an option's default, as the code computes it when the
#: option is not given (the walk below fails on a stated number that is not listed here)
USED_NUMBERS = {
    ("starforge", "--max-memory"): _memory_percent,
    ("starforge", "--max-seconds"): _seconds,
    ("starforge check", "--ambiguity"): _ambiguity,
    **{("starforge export", k): f for k, f in _BODY_NUMBERS.items()},
    **{("starforge preview", k): f for k, f in _BODY_NUMBERS.items()},
    ("starforge stars", "--marker"): lambda: [_stars_spec().marker_mm],
    ("starforge stars", "--delta"): lambda: [_stars_spec().delta_mm],
    ("starforge stars", "--gap"): lambda: [_stars_spec().gap_mm],
    ("starforge stars", "--noise"): lambda: [_stars_spec().noise_mm],
    ("starforge stars", "--work"): lambda: [_stars_spec().work],
    ("starforge stars", "--tip"): _tip,
    ("starforge stars", "--reserve"): lambda: list(_stars_spec().reserve_mm),
    ("starforge place run", "--placement-error"): _placement_error,
    ("starforge place run", "--standoff"): _standoff,
    ("starforge place-batch", "--standoff"): _standoff,
}


def test_every_number_stated_as_a_default_is_the_one_the_code_uses(root):
    """Walks every option of every command: each number in what its help says it is when not
    given is the number the code uses then (click's own [default: X] is the value click passes,
    so a number stated in words beside it must be that value too)."""
    seen = set()
    for where, p in _options(root):
        stated = [x for clause in _default_clauses(p.help) for x in _numbers(clause)]
        if not stated:
            continue
        key = (where, p.opts[0])
        seen.add(key)
        if p.default is not None and not isinstance(p.default, (bool, str)):
            assert stated == [float(p.default)], key
            continue
        assert key in USED_NUMBERS, f"{key}: its help states {stated}; add how the code gets them"
        assert stated == pytest.approx(USED_NUMBERS[key]()), key
    assert set(USED_NUMBERS) <= seen  # no entry outlives its help text


def _listed(help_text: str) -> set[str]:
    """The names a help text lists, its longest list: 'a, b (note), c or d' -> {a, b, c, d}."""
    item = r"(?!(?:a|an|the|or|and)\b)[a-z0-9]+(?: \([^()]*\))?"
    runs = [m.group(0) for m in re.finditer(rf"{item}(?:(?:, or |, | and | or ){item})+", help_text)]
    assert runs, help_text
    longest = re.sub(r" \([^()]*\)", "", max(runs, key=lambda r: r.count(" ")))
    return set(re.split(r", or |, | and | or ", longest))


def _choices():
    from starforge.cad.body import SEATS
    from starforge.cad.export import CAD_FORMATS
    from starforge.catalog import list_templates
    from starforge.props.mesh import UNITS_TO_M
    from starforge.tracking.formats import TRACKER_FORMATS
    from starforge.tracking.identify import CHOOSE

    presets = set(list_templates("presets"))
    units = set(UNITS_TO_M)
    return {
        ("starforge check", "--preset"): presets,
        ("starforge stars", "--preset"): presets,
        ("starforge check", "--choose"): set(CHOOSE),
        ("starforge check", "--world"): {"open", "closed"},
        ("starforge export", "--format"): {*CAD_FORMATS, *TRACKER_FORMATS},
        ("starforge convert", "--format"): {*TRACKER_FORMATS, "family"},
        ("starforge export", "--seat"): set(SEATS),
        ("starforge preview", "--seat"): set(SEATS),
        ("starforge stars", "--seat"): set(SEATS),
        ("starforge place run", "--units"): units,
        ("starforge place score", "--units"): units,
        ("starforge place-batch", "--units"): units,
        ("starforge place run", "--spec"): set(list_templates("place")),
        ("starforge place run", "--mesh-format"): {"glb", "stl"},
        ("starforge sweep", "--rule"): {"face", "pair"},
    }


def test_the_choices_a_help_lists_are_the_ones_the_code_knows(root):
    opts = {(where, p.opts[0]): p for where, p in _options(root)}
    for key, known in _choices().items():
        assert _listed(opts[key].help) == known, key
