"""freebody demo: each demo writes its figures (PNG and SVG) and its Markdown page, with numbers
that say what the page claims.  Short horizons keep the whole file fast."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import FAST_ENGINES, engine_param
from freebody.adapters.base import REFERENCE_ENGINE
from freebody.input.casefile import load_case
from freebody.cli import main
from freebody.tools.demo import demo_dzhanibekov, demo_integrators, demo_quiz, quiz_closed_form

QUIZ_ROUNDOFF = 1e-12  # freebody's euler-matrix vs the closed form: a few float64 operations
QUIZ_RK4_RAD = 1e-8  # RK4 on q is exact to O(h^5) for the rotation: 3e-9 rad at h = 0.1
QUIZ_EXACT_ANGLE_RAD = 1e-7  # truth vs -7.5 h^2: the world-point arm tilts as the COM falls (2e-8 rad)
QUIZ_ENGINE_MATCH_M = 1e-9  # an engine's semi-implicit map vs the reference's after two steps
ORDER_SLACK = 0.35  # fitted slopes on 3 coarse steps: pre-asymptotic by a few tenths at most
# The splitting's bounded energy error against explicit Euler's drift after 2 s at dt = 0.05 s
# (measured ratio about 1e-3): a second-order, bounded error is far below a first-order drift.
SPLITTING_BELOW_EULER = 0.05

# Every registered physics engine but the slow ones (mjx compiles for tens of seconds per run).
CLASSIC_ENGINES = [engine_param(e) for e in FAST_ENGINES if e != REFERENCE_ENGINE]


def _assert_written(res):
    assert res.page.is_file() and res.page.read_text().startswith("# ")
    for stem in res.figures:
        png, svg = stem.with_suffix(".png"), stem.with_suffix(".svg")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert b"<svg" in svg.read_bytes()[:2000]
        assert f"({png.name})" in res.page.read_text()


def test_integrators_demo(tmp_path):
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


def test_quiz_demo_closed_form_matches_euler_matrix(tmp_path):
    res = demo_quiz(tmp_path, engines=["reference"])
    _assert_written(res)
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
    rows = [r for r in res.facts["rows"] if r["label"].startswith(engine + " ")]
    assert rows and all(r["status"] == "ok" for r in rows)
    ref = next(r for r in res.facts["rows"] if r["label"] == "reference semi-implicit-explicit-gyro")
    semi = [r for r in rows if r["family"] == "semi-implicit"]
    assert semi
    for r in semi:
        np.testing.assert_allclose(r["x2"], ref["x2"], atol=QUIZ_ENGINE_MATCH_M)


def test_dzhanibekov_demo(tmp_path):
    res = demo_dzhanibekov(tmp_path, engines=["reference"], duration=3.0, dt=0.02, frames=3)
    _assert_written(res)
    gif = tmp_path / "dzhanibekov.gif"
    assert gif.read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == 3
    assert res.facts["flip_times_s"] and 2.0 < res.facts["flip_times_s"][0] < 3.0  # the first flip


def test_cli_demo_unknown_name_is_bad_input(tmp_path, capsys):
    assert main(["demo", "nosuch", "--out", str(tmp_path)]) == 2
    assert "nosuch" in capsys.readouterr().err
