"""The command line's arguments as a person types them, put in the order click parses.

* Global options (``--scheduler``, ``--max-memory``, ``--max-seconds``, ``-q``) go before the
  command for click; typed after it they are moved there, unless the command has an option of
  that name itself (``sweep --scheduler``, every long command's ``-q``).
* Options of three numbers (``--box``, ``--tip``, ``--reserve``) take ``20.8,12.6,48.3`` as well
  as ``20.8 12.6 48.3``; anything but three numbers is one line naming the option.
* The help shows no type for a flag and ``X,Y,Z`` for three numbers (:func:`polish`).
"""

from __future__ import annotations

import re

from typer.core import TyperGroup

from starforge.errors import StarforgeError

#: options of the root command that take a value, and its flags
GLOBAL_VALUES = ("--max-memory", "--max-seconds", "--scheduler")
GLOBAL_FLAGS = ("-q", "--quiet")

#: the key in click's ``ctx.meta`` that says the command was asked to be quiet
QUIET = "starforge.quiet"
#: the key in click's ``ctx.meta`` that holds the arguments as normalised (:func:`retyped`)
ARGV = "starforge.argv"


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _is_option(p) -> bool:
    return getattr(p, "param_type_name", "") == "option"


def leaf_command(group, args: list[str]):
    """The command that will parse ``args`` (a group's default subcommand included) and the index
    of the first argument after its name; (None, len(args)) when no command is named."""
    i = 0
    while i < len(args):
        a = args[i]
        if a in GLOBAL_VALUES:
            i += 2
        elif a.startswith("-"):
            i += 1
        else:
            break
    if i >= len(args):
        return None, len(args)
    cmd = group.commands.get(args[i])
    i += 1
    while hasattr(cmd, "commands"):
        if i < len(args) and args[i] in cmd.commands:
            cmd, i = cmd.commands[args[i]], i + 1
        else:
            cmd = cmd.commands.get(getattr(cmd, "default_command", ""))
    return cmd, i


def option_names(cmd) -> set[str]:
    return {o for p in (cmd.params if cmd else ()) for o in (*p.opts, *p.secondary_opts)}


def triples(cmd) -> set[str]:
    """The names of ``cmd``'s options of three numbers."""
    return {o for p in (cmd.params if cmd else ()) if _is_option(p) and p.nargs == 3 for o in p.opts}


def normalise(group, args: list[str], meta: dict) -> list[str]:
    """``args`` in the order and form click parses (see the module docstring); ``meta[QUIET]`` set
    when ``-q``/``--quiet`` is given anywhere, ``meta[ARGV]`` the arguments as the user ordered them
    (for :func:`retyped`, without the command's own ``-q`` added here)."""
    cmd, start = leaf_command(group, args)
    own, three = option_names(cmd), triples(cmd)
    head, tail = list(args[:start]), []
    i = start
    while i < len(args):
        a = args[i]
        if a == "--":
            tail += args[i:]
            break
        name = a.split("=", 1)[0]
        if a in GLOBAL_FLAGS:
            meta[QUIET] = True
        if name in (*GLOBAL_VALUES, *GLOBAL_FLAGS) and name not in own:
            width = 2 if a in GLOBAL_VALUES else 1
            head = [*args[i : i + width], *head]
            i += width
            continue
        if a in three:
            values, j = _three(a, args, i + 1)
            tail += [a, *values]
            i = j
            continue
        tail.append(a)
        i += 1
    meta[ARGV] = head + tail
    if any(a in GLOBAL_FLAGS for a in head):
        meta[QUIET] = True
        if "-q" in own and not any(a in GLOBAL_FLAGS for a in tail):
            tail.insert(0, "-q")  # quiet before the command: the command's own -q too
    return head + tail


def _three(flag: str, args: list[str], i: int) -> tuple[list[str], int]:
    """The three numbers after ``flag`` at ``args[i:]`` (comma-separated or not) and the index after them."""
    values: list[str] = []
    j = i
    while j < len(args) and len(values) < 3:
        parts = [p for p in args[j].split(",") if p.strip()] if "," in args[j] else [args[j]]
        if not all(_number(p) for p in parts):
            break
        values += [p.strip() for p in parts]
        j += 1
    if len(values) != 3:
        got = " ".join(args[i:j]) if j > i else "nothing"
        raise StarforgeError(
            f"{flag} needs 3 values, e.g. {flag} 20.8,12.6,48.3 or {flag} 20.8 12.6 48.3 (mm); got {got}"
        )
    return values, j


def polish(cmd) -> None:
    """Help text details for every option under ``cmd``: flags show no type, three numbers show
    ``X,Y,Z``."""
    for p in cmd.params:
        if _is_option(p):
            if p.is_flag:
                p.metavar = ""
            elif p.nargs == 3 and p.metavar is None:
                p.metavar = "X,Y,Z"
    plain_help = cmd.get_help_option

    def help_option(ctx, _plain=plain_help):
        opt = _plain(ctx)
        if opt is not None:
            opt.metavar = ""
        return opt

    cmd.get_help_option = help_option
    for sub in getattr(cmd, "commands", {}).values():
        polish(sub)


class RootGroup(TyperGroup):
    """The ``starforge`` group: arguments normalised (:func:`normalise`), help polished (:func:`polish`)."""

    def __init__(self, *a, **kw) -> None:
        super().__init__(*a, **kw)
        polish(self)

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        args = normalise(self, list(args), ctx.meta)
        return super().parse_args(ctx, args)



def _takes_value(token: str) -> bool:
    return not token.startswith("-") or _number(token)


def retyped(meta: dict, changes: dict) -> str:
    """The user's command line with some options changed, for a message to suggest:
    ``changes[flag]`` is the new value(s) (a string or a list; None drops the option); an option
    not given is added at the end.  Everything else the user typed is kept."""
    import shlex

    args = list(meta.get(ARGV, ()))
    out: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        flag = a.split("=", 1)[0]
        i += 1
        if flag not in changes:
            out.append(a)
            continue
        n = 0
        while "=" not in a and i < len(args) and _takes_value(args[i]) and (n == 0 or flag in _MANY):
            i, n = i + 1, n + 1
    for flag, value in changes.items():
        if value is not None:
            out += [flag, *([value] if isinstance(value, str) else [str(v) for v in value])]
    return "starforge " + shlex.join(out)


#: options that take several values after one flag
_MANY = {"--box", "--tip", "--reserve", "--avoid"}


#: a library message that starts with a parameter's name: ``noise must be >= 0``,
#: ``body options.stem_mm must be finite``, ``cube has 1991 values``, ``marker diameter must ...``
_LEADING_NAME = re.compile(r"(?:[a-z ]+\.)?([a-z_]+)(?=(?: diameter)? (?:must|has|is)\b)")


def as_typed(message: str, group, argv: list[str]) -> str:
    """``message`` with a leading parameter name replaced by the option the user typed for it
    (``noise must be >= 0`` -> ``--noise must be >= 0``); unchanged when it starts otherwise or
    the user typed no such option (the value then came from a file, which the message names)."""
    m = _LEADING_NAME.match(message)
    if m is None:
        return message
    cmd, _ = leaf_command(group, argv)
    typed = {a.split("=", 1)[0] for a in argv if a.startswith("--")}
    for p in cmd.params if cmd is not None else ():
        flag = next((o for o in p.opts if o in typed), None)
        names = {p.name, f"{p.name}_mm", *(o.lstrip("-").replace("-", "_") for o in p.opts)}
        if _is_option(p) and flag is not None and m.group(1) in names:
            return flag + message[m.end() :]
    return message
