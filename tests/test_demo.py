"""freebody demo: each demo writes its figures (PNG and SVG) and its Markdown page, with numbers
that say what the page claims; every slide is 16:9 with the truth drawn on top, the GIF at least
640 px wide.  Short horizons keep the whole file fast."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import FAST_ENGINES, engine_param
from freebody.adapters.base import REFERENCE_ENGINE
from freebody.input.casefile import load_case
from freebody.cli import main
from freebody.tools import demo
from freebody.tools.demo import demo_dzhanibekov, demo_integrators, demo_quiz, quiz_closed_form

QUIZ_ROUNDOFF = 1e-12  # freebody's euler-matrix vs the closed form: a few float64 operations
QUIZ_RK4_RAD = 1e-8  # RK4 on q is exact to O(h^5) for the rotation: 3e-9 rad at h = 0.1
QUIZ_EXACT_ANGLE_RAD = 1e-7  # truth vs -7.5 h^2: the world-point arm tilts as the COM falls (2e-8 rad)
QUIZ_ENGINE_MATCH_M = 1e-9  # an engine's semi-implicit map vs the reference's after two steps
ORDER_SLACK = 0.35  # fitted slopes on 3 coarse steps: pre-asymptotic by a few tenths at most
# The splitting's bounded energy error against explicit Euler's drift after 2 s at dt = 0.05 s
# (measured ratio about 1e-3): a second-order, bounded error is far below a first-order drift.
SPLITTING_BELOW_EULER = 0.05

SLIDE_ASPECT = 16 / 9
SLIDE_ASPECT_RTOL = 0.01  # pixel rounding of a 16:9 figure at any dpi is far below 1 %
GIF_MIN_WIDTH_PX = 640  # a GIF a projector shows without upscaling it into blur
# euler-matrix-gs's one-step error coefficient on long_horizon (I1 + I2 = I3): 1/6 predicted, 0.168
# measured at h = 1e-3 s (the h^3 term); lie-euler's 0.8427, 0.8424 measured
GS_ONE_STEP_RTOL = 0.02

# Every registered physics engine but the slow ones (mjx compiles for tens of seconds per run).
CLASSIC_ENGINES = [engine_param(e) for e in FAST_ENGINES if e != REFERENCE_ENGINE]


def _assert_written(res):
    from PIL import Image

    assert res.page.is_file() and res.page.read_text().startswith("# ")
    for stem in res.figures:
        png, svg = stem.with_suffix(".png"), stem.with_suffix(".svg")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert b"<svg" in svg.read_bytes()[:2000]
        assert f"({png.name})" in res.page.read_text()
        with Image.open(png) as im:
            w, h = im.size
        assert w / h == pytest.approx(SLIDE_ASPECT, rel=SLIDE_ASPECT_RTOL), (png.name, im.size)


@pytest.fixture
def saved_figures(monkeypatch):
    """The matplotlib Figures the demos save, by file stem (demo._save wrapped)."""
    figs = {}
    save = demo._save

    def _record(fig, out_dir, stem):
        figs[stem] = fig
        return save(fig, out_dir, stem)

    monkeypatch.setattr(demo, "_save", _record)
    return figs


def _assert_truth_on_top(fig, stem):
    """In every axes that draws the truth: its artists are above every other data artist (lines,
    bars, collections; the legend apart) and the truth comes first in the axes' or figure's legend."""
    axes_with_truth = 0
    for ax in fig.axes:
        artists = [a for a in (*ax.lines, *ax.patches, *ax.collections)]
        truth = [a for a in artists if a.get_gid() == demo.TRUTH_GID]
        if not truth:
            continue
        axes_with_truth += 1
        others = [a for a in artists if a.get_gid() != demo.TRUTH_GID]
        assert min(a.get_zorder() for a in truth) > max(a.get_zorder() for a in others), stem
        legend = ax.get_legend() or (fig.legends[0] if fig.legends else None)
        if legend is not None:
            assert legend.get_texts()[0].get_text().startswith("truth"), (stem, legend.get_texts()[0])
    assert axes_with_truth, f"{stem}: no truth drawn"


def test_integrators_demo(tmp_path, saved_figures):
    res = demo_integrators(tmp_path, dt=0.05, duration=2.0, convergence_duration=1.0,
                           convergence_dts=(0.1, 0.05, 0.025))
    _assert_written(res)
    assert len(res.figures) == 4
    slopes = res.facts["slopes"]
    for name in ("euler-matrix", "euler-quat", "lie-euler"):
        assert abs(slopes[name] - 1) < ORDER_SLACK, (name, slopes)
    assert abs(slopes["symplectic-splitting"] - 2) < ORDER_SLACK, slopes
    assert abs(slopes["rk4"] - 4) < ORDER_SLACK, slopes
    assert res.facts["orthonormality_final"] > 1e-3  # R drifts without Gram-Schmidt
    final = res.facts["final"]  # signed energy errors: explicit Euler gains, the splitting oscillates
    assert final["euler-matrix"]["energy"] > 0 and final["euler-quat"]["energy"] > 0
    split = final["symplectic-splitting"]
    assert split["energy_min_signed"] < 0 < split["energy_max_signed"]
    assert split["energy_max"] < SPLITTING_BELOW_EULER * final["euler-quat"]["energy"]
    page = res.page.read_text()
    assert "symplectic-splitting" in page and "(symplectic)" not in page
    _assert_truth_on_top(saved_figures["integrators_energy"], "integrators_energy")
    # why euler-matrix-gs fits more than 1: its one-step error, measured as predicted, and the page says so
    gs = res.facts["gram_schmidt"]["one_step"]
    for name in ("euler-matrix-gs", "lie-euler"):
        assert gs["measured"][name] == pytest.approx(gs["predicted"][name], rel=GS_ONE_STEP_RTOL)
    assert gs["measured"]["euler-matrix-gs"] < 0.5 * gs["measured"]["lie-euler"]
    assert f"fits {slopes['euler-matrix-gs']:.2f} and not 1" in page
    assert abs(res.facts["gram_schmidt"]["contrast_slope"] - 1) < ORDER_SLACK  # no cancellation there


def test_quiz_demo_closed_form_matches_euler_matrix(tmp_path, saved_figures):
    res = demo_quiz(tmp_path, engines=["reference"])
    _assert_written(res)
    _assert_truth_on_top(saved_figures["quiz_t2"], "quiz_t2")
    h = 0.1
    cf = quiz_closed_form(load_case("quiz"), h)
    np.testing.assert_allclose(cf["w1"], [0, 0, -5 * h], atol=QUIZ_ROUNDOFF)
    np.testing.assert_allclose(cf["L2"], [0, 0, -2 * h], atol=QUIZ_ROUNDOFF)
    rows = {r["label"]: r for r in res.facts["rows"]}
    np.testing.assert_allclose(rows["reference euler-matrix"]["x2"], cf["x2"], atol=QUIZ_ROUNDOFF)
    assert rows["reference euler-matrix"]["angle2"] == pytest.approx(np.arctan(-5 * h * h), abs=QUIZ_ROUNDOFF)
    assert "symplectic" not in res.page.read_text()  # the engines' map is semi-implicit Euler, by its reference names
    # semi-implicit leads (-10 h^2), rk4 and the truth agree (-7.5 h^2), explicit Euler lags
    assert rows["reference semi-implicit-explicit-gyro"]["angle2"] == pytest.approx(-10 * h * h, abs=QUIZ_ROUNDOFF)
    assert rows["reference rk4"]["angle2"] == pytest.approx(rows["truth (DOP853)"]["angle2"], abs=QUIZ_RK4_RAD)
    assert rows["truth (DOP853)"]["angle2"] == pytest.approx(-7.5 * h * h, abs=QUIZ_EXACT_ANGLE_RAD)


@pytest.mark.parametrize("classic_engine", CLASSIC_ENGINES)
def test_quiz_demo_runs_the_engine(classic_engine, tmp_path):
    engine = classic_engine
    res = demo_quiz(tmp_path, engines=[engine])
    rows = [r for r in res.facts["rows"] if r["label"] == engine or r["label"].startswith(engine + " ")]
    assert rows and all(r["status"] == "ok" for r in rows), [(r["label"], r["status"]) for r in rows]
    ref = next(r for r in res.facts["rows"] if r["label"] == "reference semi-implicit-explicit-gyro")
    semi = [r for r in rows if r["family"] == "semi-implicit"]
    assert semi
    for r in semi:
        np.testing.assert_allclose(r["x2"], ref["x2"], atol=QUIZ_ENGINE_MATCH_M)


def test_dzhanibekov_demo(tmp_path, saved_figures):
    res = demo_dzhanibekov(tmp_path, engines=["reference"], duration=3.0, dt=0.02, frames=3)
    _assert_written(res)
    _assert_truth_on_top(saved_figures["dzhanibekov_flip"], "dzhanibekov_flip")
    gif = tmp_path / "dzhanibekov.gif"
    assert gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == 3
        assert im.size[0] >= GIF_MIN_WIDTH_PX, im.size
    assert res.facts["flip_times_s"] and 2.0 < res.facts["flip_times_s"][0] < 3.0  # the first flip
    stats = {s["label"]: s for s in res.facts["run_stats"]}
    assert stats["reference/rk4"]["flips_on_time"] == 1  # rk4 flips with the truth
    page = res.page.read_text()
    for label in stats:  # a sentence for every row of the table
        assert f"- `{label}` " in page


def test_cli_demo_unknown_name_is_bad_input(tmp_path, capsys):
    assert main(["demo", "nosuch", "--out", str(tmp_path)]) == 2
    assert "nosuch" in capsys.readouterr().err


def test_every_demo_page_is_a_shipped_template():
    """Each demo's page text is a template file shipped as package data (an installed freebody has
    it) whose fields are all named (the tests above fill them: a missing one is a KeyError)."""
    import string
    import tomllib
    from fnmatch import fnmatch
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    shipped = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    for name in demo.DEMOS:
        rel = f"{demo.TEMPLATES}/{name}.md"
        assert any(fnmatch(rel, pattern) for pattern in shipped.get("freebody.tools", [])), rel
        fields = {f.split("[")[0].split(".")[0] for _, f, _, _ in string.Formatter().parse(demo._template(name))
                  if f is not None}
        assert fields and "" not in fields, name  # named fields only, no positional {}
