"""Options that take several values after one flag (``--avoid A.xml B.vsk``).

Click, and so Typer, gives an option one value per flag (``--avoid A --avoid B``).  A command
that also accepts ``--avoid A B`` declares ``context_settings=MULTI`` and passes its
context's extra arguments (the bare values click could not place) to :func:`more_values`.
"""

from __future__ import annotations

from pathlib import Path

#: context settings of a command with a multi-value option: bare extra values are kept, unknown
#: options are still refused by click
MULTI = {"allow_extra_args": True}


def more_values(flag: str, given, extra) -> list[Path]:
    """The values of ``flag``: those given with the flag (repeated or not) followed by the bare
    values after it (``extra``, click's ``ctx.args``).  Extra values without the flag are an
    error naming them, as click reports them."""
    from starforge.errors import StarforgeError

    given = list(given or [])
    extra = [str(x) for x in (extra or [])]
    if extra and not given:
        raise StarforgeError(f"got unexpected extra argument(s): {' '.join(extra)}")
    bad = [x for x in extra if x.startswith("-")]
    if bad:
        raise StarforgeError(f"no such option: {bad[0]}")
    return [Path(p) for p in given] + [Path(p) for p in extra]


def spread_flag(flag: str, args: list[str]) -> list[str]:
    """``args`` with every bare value that follows ``flag`` (up to the next option or ``--``)
    given its own ``flag``: ``--avoid A B hammer`` -> ``--avoid A --avoid B --avoid hammer``.

    For a command that also has an optional positional argument (``place [PROP]``), where
    click would otherwise take the second value for the positional: the rule is that every
    value after the flag until the next option belongs to the flag, so a positional comes
    before the flag or after another option.
    """
    out: list[str] = []
    taking = False
    for a in args:
        if a == "--":
            taking = False
            out.append(a)
            continue
        if a.startswith("-") and a != "-":
            taking = a == flag or a.startswith(flag + "=")
            out.append(a)
            if a == flag:
                taking = "value"  # the flag's own value comes next
            continue
        if taking == "value":
            taking = True
            out.append(a)
        elif taking:
            out += [flag, a]
        else:
            out.append(a)
    return out
