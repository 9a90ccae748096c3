"""Pictures read at a glance: no text box overlaps another or leaves the figure."""

from __future__ import annotations

import itertools

import pytest

from starforge.render import _mpl


def _overlaps(fig) -> list:
    """Pairs of text boxes that overlap (by more than a pixel) and texts outside the figure."""
    from matplotlib.transforms import Bbox

    boxes = _mpl.text_boxes(fig)
    w, h = fig.bbox.width, fig.bbox.height
    bad = [(t, "outside") for t, (x0, y0, x1, y1) in boxes if x0 < -1 or y0 < -1 or x1 > w + 1 or y1 > h + 1]
    for (a, p), (b, q) in itertools.combinations(boxes, 2):
        if _mpl.boxes_overlap(Bbox.from_extents(*p), Bbox.from_extents(*q), pad=1.0):
            bad.append((a, b))
    return bad


@pytest.fixture
def figures(monkeypatch):
    """Every figure a render function saves, checked before it is closed."""
    found: list = []
    real = _mpl.save_png

    def keep(fig, path, dpi=100):
        fig.set_dpi(dpi)
        found.append((str(path), _overlaps(fig), len(_mpl.text_boxes(fig))))
        return real(fig, path, dpi)

    import starforge.render.bodies as bodies
    import starforge.render.tracking as tracking

    monkeypatch.setattr(_mpl, "save_png", keep)
    monkeypatch.setattr(tracking, "save_png", keep)
    return found, bodies


def test_check_png_title_fits_and_nothing_overlaps(figures, tmp_path):
    from starforge.render.tracking import rates_plot

    found, _ = figures
    doc = {
        "curve": {"noise_mm": [0.0, 0.2, 0.4], "frames": 1000, "identification_rate": [1, 0.9, 0.5],
                  "mislabel_rate": [0, 0.01, 0.2]},
        "settings": {"noise_mm": 0.2, "world": "open", "drop": 1, "drop_mode": "uniform 0..drop", "ghosts": 3,
                     "match_mm": 1.21776, "choose": None},
        "input": {"bodies": 1234},
    }  # fmt: skip
    rates_plot(doc, tmp_path / "check.png")
    ((path, bad, n),) = found
    assert n > 5 and bad == []


@pytest.mark.slow
def test_body_previews_and_sheet_have_no_overlapping_text(figures, small_family, tmp_path):
    from starforge.cad.body import BodySpec
    from starforge.cad.export import family_bodies
    from starforge.cad.mounts import load_mount
    from starforge.stars.model import load_family

    found, bodies = figures
    fam, _ = small_family
    family = load_family(fam / "family.json")
    bs = family_bodies(family, [1, 2, 3], load_mount("flat"), BodySpec())
    bodies.draw_previews(bs, tmp_path / "preview", family.spec.box_mm)
    assert len(found) == 4
    for path, bad, n in found:
        assert n >= 2 and bad == [], path
    sheet = [f for f in found if f[0].endswith("sheet.png")]
    assert sheet and sheet[0][2] >= 4  # an id and size per body and the note


@pytest.mark.slow
def test_drawing_a_picture_leaves_a_notebooks_matplotlib_as_it_was(tmp_path):
    """A notebook that draws its own figures (another backend, its own settings, a figure open)
    calls starforge's pictures in its own process: afterwards its backend, its settings and its
    figures are the same, and the picture is the one the CLI's render process draws (unhinted
    text, whatever the notebook's setting)."""
    import subprocess
    import sys
    from pathlib import Path

    family = Path(__file__).parent / "data" / "cad" / "small_family.json"
    code = f"""
import matplotlib
matplotlib.use("svg")
import matplotlib.pyplot as plt
plt.figure()
matplotlib.rcParams["text.hinting"] = "force_autohint"
before = dict(matplotlib.rcParams)
from starforge.render.stars import family_sheet
from starforge.stars.model import load_family
family_sheet(load_family({str(family)!r}), {str(tmp_path / "in_notebook.png")!r})
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
assert plt.get_fignums() == [1], plt.get_fignums()
changed = [k for k, v in matplotlib.rcParams.items() if before[k] != v]
assert not changed, changed
"""
    subprocess.run([sys.executable, "-c", code], check=True)
    from starforge.render.stars import family_sheet
    from starforge.stars.model import load_family

    family_sheet(load_family(family), tmp_path / "here.png")
    assert (tmp_path / "in_notebook.png").read_bytes() == (tmp_path / "here.png").read_bytes()
