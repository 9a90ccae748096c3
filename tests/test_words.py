"""Counts in words: the singular for one, the plural otherwise, and back."""

from __future__ import annotations

import doctest

import pytest

import starforge.words as words
from starforge.words import counted, plural, singular

#: nouns the command line counts, with their plurals written out by hand
NOUNS = {
    "star": "stars",
    "body": "bodies",
    "picture": "pictures",
    "candidate": "candidates",
    "bed": "beds",
    "frame": "frames",
    "file": "files",
    "rule violation": "rule violations",
    "box": "boxes",
    "batch": "batches",
    "day": "days",
}


@pytest.mark.parametrize(("one", "many"), NOUNS.items())
def test_plural_and_singular_are_inverse(one, many):
    assert plural(one) == many
    assert singular(many) == one


@pytest.mark.parametrize("n", [0, 1, 2, 25, 1000])
def test_only_one_reads_in_the_singular(n):
    text = counted(n, "body")
    assert text.split(" ", 1)[0] == str(n)
    assert text.endswith(" body") == (n == 1) and text.endswith(" bodies") == (n != 1)


def test_docstring_examples_run():
    assert doctest.testmod(words).failed == 0
