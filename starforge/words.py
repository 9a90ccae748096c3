"""Counts in words: ``1 star``, ``25 stars``, ``1 body``, ``3 bodies``."""

from __future__ import annotations


def plural(noun: str) -> str:
    """The plural of a regular English noun.

    Examples
    --------
    >>> [plural(w) for w in ("star", "body", "box", "day")]
    ['stars', 'bodies', 'boxes', 'days']
    """
    if noun.endswith("y") and noun[-2:-1] not in ("a", "e", "i", "o", "u"):
        return noun[:-1] + "ies"
    if noun.endswith(("s", "x", "ch", "sh")):
        return noun + "es"
    return noun + "s"


def singular(nouns: str) -> str:
    """The singular of a regular English plural (the inverse of :func:`plural`).

    Examples
    --------
    >>> [singular(w) for w in ("pictures", "bodies", "boxes", "candidates")]
    ['picture', 'body', 'box', 'candidate']
    """
    if nouns.endswith("ies"):
        return nouns[:-3] + "y"
    if nouns.endswith(("sses", "xes", "ches", "shes")):
        return nouns[:-2]
    return nouns.removesuffix("s")


def counted(n: int, noun: str, form: str = "{n}") -> str:
    """``n`` and ``noun`` (singular), the noun in the plural unless ``n`` is 1; ``form`` formats
    the number.

    Examples
    --------
    >>> counted(1, "picture"), counted(3, "body"), counted(12000, "candidate", "{n:,}")
    ('1 picture', '3 bodies', '12,000 candidates')
    """
    return f"{form.format(n=n)} {noun if n == 1 else plural(noun)}"


def one_of(names) -> str:
    """Names as a person lists them: ``"a, b or c"``.

    Examples
    --------
    >>> one_of(["art", "ndi", "vicon"]), one_of(["glb"])
    ('art, ndi or vicon', 'glb')
    """
    names = list(names)
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
