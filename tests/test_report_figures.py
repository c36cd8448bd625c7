"""The per-case figures drawn fast without changing what they show: a line is drawn through its
per-pixel-column envelope (same pixels, maxima and ends kept), the error series are the metrics'
(each truth read once), and the figures are the same whether drawn in one process or several."""
from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from freebody.cli import main
from freebody.reference_impl.problem import Problem
from freebody.report import data as rd
from freebody.report import plots
from freebody.report.render import convergence_of
from freebody.results.document import load_trajectory
from freebody.run.metrics import series

# |series recomputed for the report - metrics.series| on the same arrays: the same formulas, so
# round-off of a different operation grouping at most.
SERIES_RTOL = 1e-12
# Envelope against every sample of a 200 000-sample random walk (the worst case: a dense band),
# drawn on the Agg canvas: where anti-aliased segments overlap, the shading depends a little on
# which samples are joined.  Measured 4.7 % of the line's pixels differing by more than a quarter
# of the grey range (36 % with an 800-sample stride); smooth curves differ far less.
ENVELOPE_PIXEL_FRACTION = 0.06


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """The reference engine on two cases with gravity and loads (offset_push) and without (quiz),
    at two time steps."""
    out = tmp_path_factory.mktemp("figures_run")
    assert main(["run", "quiz", "offset_push", "--engine", "reference", "--integrator", "euler-quat",
                 "--integrator", "rk4", "--duration", "0.3", "--dt", "0.01", "--dt", "0.005",
                 "--out", str(out), "--quiet", "--no-report"]) == 0
    return out


def _random_walk(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return np.linspace(0.0, 10.0, n), np.cumsum(rng.normal(size=n))


def test_envelope_keeps_ends_and_extremes():
    x, y = _random_walk(100_000)
    keep = plots.envelope(x, y, 300)
    assert np.all(np.diff(keep) > 0) and len(keep) <= 4 * 300
    assert {0, len(x) - 1, int(np.argmax(y)), int(np.argmin(y))} <= set(keep.tolist())
    small = plots.envelope(x[:1000], y[:1000], 300)
    assert np.array_equal(small, np.arange(1000))  # few samples: all of them
    flat = plots.envelope(np.zeros(5000), y[:5000], 300)
    assert len(flat) == 5000  # no x extent: nothing to bin


def _draw(x, y) -> np.ndarray:
    from PIL import Image

    fig = plots._figure(5.0, 3.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(x, y, linewidth=1, color="tab:blue")
    return np.asarray(Image.open(io.BytesIO(plots.png_bytes(fig))).convert("L")).astype(int)


def test_envelope_draws_the_same_line():
    x, y = _random_walk(200_000)
    fig = plots._figure(5.0, 3.0)
    columns = plots._columns(fig.add_subplot(1, 1, 1))
    keep = plots.envelope(x, y, plots.ENVELOPE_PER_PIXEL * columns)
    full, thin = _draw(x, y), _draw(x[keep], y[keep])
    line = full < 250
    differ = np.abs(full - thin) > 64
    assert differ.sum() <= ENVELOPE_PIXEL_FRACTION * line.sum()


def test_report_series_are_the_metrics_series(run_dir):
    doc = json.loads((run_dir / "results.json").read_text())
    for case in ("quiz", "offset_push"):
        physics = rd.case_physics(doc, case)
        problem = Problem(case, "", physics.body, None, physics.gravity)
        for dt in (0.01, 0.005):
            runs = [r for r in doc["runs"] if r["case"] == case and r["dt"] == dt]
            reader = rd.SeriesReader(physics)
            for r in runs:
                got, truth = reader.read(run_dir / r["trajectory"], r)
                tr, tr_truth = load_trajectory(run_dir / r["trajectory"])
                want = series(problem, tr, tr_truth)
                for name in ("orientation_error", "energy_error", "angular_momentum_error"):
                    np.testing.assert_allclose(getattr(got, name), getattr(want, name),
                                               rtol=SERIES_RTOL, atol=0.0, err_msg=name)
                assert np.max(got.orientation_error) == pytest.approx(
                    r["metrics"]["orientation_error_max_rad"], rel=SERIES_RTOL)
            assert len(reader._truths) == 1  # one truth per case and dt, read once


def test_figures_are_the_same_in_one_process_or_several(run_dir):
    doc = json.loads((run_dir / "results.json").read_text())
    runs, conv = doc["runs"], convergence_of(doc)
    physics = {c: rd.case_physics(doc, c) for c in rd.by_case(runs)}
    serial, notes1 = plots.render_figures(runs, conv, physics, run_dir, jobs=1)
    parallel, notes2 = plots.render_figures(runs, conv, physics, run_dir, jobs=2)
    assert list(serial) == list(parallel) == ["heatmap", "convergence", "speed", ("quiz", 0.01),
                                              ("quiz", 0.005), ("offset_push", 0.01), ("offset_push", 0.005)]
    assert serial == parallel and notes1 == notes2
    assert all(png.startswith(b"\x89PNG") for png in serial.values())


def _case_figures(run_dir: Path, order: list[tuple[str, float, bool]], fresh: bool) -> list[bytes]:
    """case_dt's PNGs in this order of (case, dt, with the case's mass properties): each on a new
    figure with its legend drawn in (fresh), or on the figure of the one before with the legend
    drawn once (as render_figures draws them)."""
    doc = json.loads((run_dir / "results.json").read_text())
    runs = doc["runs"]
    plots.forget_drawn()
    out = []
    for case, dt, with_physics in order:
        if fresh:
            plots.forget_drawn()
        physics = rd.case_physics(doc, case) if with_physics else None
        at = [r for r in runs if r["case"] == case and r["dt"] == dt]
        out.append(plots.case_dt(case, dt, at, physics, run_dir, rd.labels(runs))[0])
    return out


def test_a_reused_figure_and_a_legend_drawn_once_give_the_same_bytes(run_dir):
    # between figures the panels change scale (an empty panel is linear, with a note), limits and
    # lines; the reused figure must forget all of it
    order = [("offset_push", 0.01, True), ("quiz", 0.005, False), ("offset_push", 0.005, True),
             ("quiz", 0.01, True), ("offset_push", 0.01, False)]
    reused = _case_figures(run_dir, order, fresh=False)
    assert plots._CASE_FIGURE is not None and list(plots._LEGENDS.values()) != [None]  # both kept
    fresh = _case_figures(run_dir, order, fresh=True)
    assert all(png.startswith(b"\x89PNG") for png in fresh)
    assert reused == fresh


def test_a_legend_is_drawn_in_where_its_place_is_not_blank(run_dir):
    doc = json.loads((run_dir / "results.json").read_text())
    runs = [r for r in doc["runs"] if r["case"] == "quiz" and r["dt"] == 0.01]
    labs = rd.labels(runs)

    def draw(place_text_under_legend: bool, fresh: bool) -> bytes:
        if fresh:
            plots.forget_drawn()
        fig = plots._figure(6.0, 3.0)
        ax = fig.add_axes((0.1, 0.15, 0.5, 0.7))
        handles = {lab: ax.plot([0, 1], [k, k + 1], **plots.styles(labs)[lab])[0] for k, lab in enumerate(labs)}
        if place_text_under_legend:
            fig.text(0.97, 0.8, "under", ha="right", fontsize=7)
        return plots._with_legend(fig, handles, labs, top=0.9)

    plain = draw(True, fresh=True)
    draw(False, fresh=True)  # the legend's pixels drawn alone, kept
    with pytest.raises(plots.OverlayRefused):  # not blank there: refused, so drawn in
        plots.png_bytes(_figure_with_text_at(0.97, 0.8, 6.0, 3.0), overlay=list(plots._LEGENDS.values())[0])
    assert draw(True, fresh=False) == plain


def _figure_with_text_at(x: float, y: float, w: float, h: float):
    fig = plots._figure(w, h)
    fig.text(x, y, "under", ha="right", fontsize=7)
    return fig


def test_report_html_is_written_before_its_figures_with_places_for_them(run_dir):
    from freebody.report import html

    doc = json.loads((run_dir / "results.json").read_text())
    runs, conv = doc["runs"], convergence_of(doc)
    physics = {c: rd.case_physics(doc, c) for c in rd.by_case(runs)}
    fill = html.render_html_later(doc, conv, physics, run_dir)  # before any figure is drawn
    keys = ["heatmap", "convergence", "speed"] + [(c, dt) for c, rs in rd.by_case(runs).items() for dt in rd.dts(rs)]
    drawn = {key: b"\x89PNG" + repr(key).encode() for key in keys}
    page = fill(drawn, {"quiz": ["first <note>", "second"]})
    last = rd.dts(rd.by_case(runs)["quiz"])[-1]
    quiz_last = html.img(drawn["quiz", last], f"quiz dt={last:g}", rd.figure_anchor("quiz", last))
    notes = '\n<p class="note">first &lt;note&gt;</p>\n<p class="note">second</p>'
    assert quiz_last + notes + "\n<h2" in page  # the notes after the case's last figure, as before
    assert all(html.img(png, "", None).split('src="')[1] in page for png in drawn.values())
    assert "\x00" not in page
    none_drawn = fill(dict.fromkeys(keys), {})
    assert f'<p class="note" id="{rd.figure_anchor("quiz", last)}">(quiz dt={last:g}: nothing to plot)</p>\n<h2' in none_drawn
    assert html.render_html(doc, conv, physics, drawn, {}, run_dir) == page.replace(notes, "")


# --- every text inside its figure; colours --------------------------------------------------------------

def test_a_cut_label_is_found_and_the_figure_grown_to_hold_it():
    fig = plots._figure(4.0, 3.0)
    ax = fig.add_axes((0.0, 0.1, 1.0, 0.8))  # no margin: the tick labels fall outside
    ax.set_yticks([0.0, 1.0], ["a rather long tick label", "another one"])
    ax.set_title("a title")
    assert plots.clipped_texts(fig)  # found
    png = plots.png_bytes(fig)  # grown to hold them, no error
    assert plots.clipped_texts(fig) == []
    from PIL import Image

    assert Image.open(io.BytesIO(png)).size[0] > 4.0 * plots.DPI


def test_a_text_that_cannot_fit_fails_loudly():
    fig = plots._figure(4.0, 3.0)
    fig.add_subplot(1, 1, 1)
    fig.text(-0.6, 0.5, "anchored outside the figure")  # moves with the figure's edge: never fits
    with pytest.raises(plots.ClippedText, match="anchored outside"):
        plots.png_bytes(fig)


def test_every_figure_keeps_its_text_inside(run_dir, monkeypatch):
    """Every figure of the report (heat map per dt, convergence, speed, per-case) after fitting:
    no text beyond its edge; the heat map has one panel per time step."""
    doc = json.loads((run_dir / "results.json").read_text())
    runs, conv = doc["runs"], convergence_of(doc)
    # long labels and case names, as an engine with a long integrator name makes them
    for r in runs:
        r["integrator"] = r["integrator"] + "-with-a-rather-long-integrator-name"
    seen = []
    real = plots.png_bytes

    def check(fig, overlay=None):  # a legend drawn once was checked alone (plots.drawn_alone)
        png = real(fig, overlay)
        seen.append((fig, plots.text_overflow(fig)[1]))
        return png

    monkeypatch.setattr(plots, "png_bytes", check)
    physics = {c: rd.case_physics(doc, c) for c in rd.by_case(runs)}
    figures, _ = plots.render_figures(runs, conv, physics, run_dir, jobs=1)
    assert all(png is not None for png in figures.values()) and len(seen) == len(figures)
    assert [names for _, names in seen] == [[]] * len(seen)
    heat = seen[0][0]
    assert len([ax for ax in heat.axes if ax.images]) == len(rd.dts(runs))  # one panel per dt


def test_colour_per_engine_style_per_integrator():
    labs = ["reference/rk4", "reference/euler-quat", "mujoco/Euler", "mujoco/RK4", "pybullet/maximal"]
    st = plots.styles(labs)
    assert st["reference/rk4"]["color"] == st["reference/euler-quat"]["color"] == plots.REFERENCE_COLOUR
    assert st["mujoco/Euler"]["color"] == st["mujoco/RK4"]["color"] == plots.OKABE_ITO[0]
    assert st["pybullet/maximal"]["color"] == plots.OKABE_ITO[1]
    within = [(st[lab]["linestyle"], st[lab]["marker"]) for lab in labs[:2]]
    assert len(set(within)) == 2
