"""Teaching demos: slide-ready figures (PNG and SVG) and a short Markdown page per demo.

- ``integrators``: the signed energy error (explicit Euler gains energy, the symplectic splitting's
  error oscillates and stays bounded) and the orientation error against time for the lecture's
  schemes on a tumbling body, the orthonormality error of R without Gram-Schmidt, and the
  convergence plot with fitted slopes (about 1 for the Euler family, 2 for the splitting, 4 for RK4),
  with why ``euler-matrix-gs`` fits more than 1 on this body (:func:`gram_schmidt_one_step`).
- ``quiz``: the lecture's one-step push quiz worked out in closed form for explicit Euler, checked
  against freebody's ``euler-matrix``, and set beside the engines' semi-implicit Euler maps
  (``semi-implicit-explicit-gyro`` / ``semi-implicit-implicit-gyro``) and RK4.
- ``dzhanibekov``: the flip of the intermediate axis in body- and world-frame angular velocity and the
  signed energy error for each engine, the flip times of each run against the truth's, and a GIF of
  the tumbling box beside its angular velocity.

Every slide is 16:9 (:data:`SLIDE_SIZE_IN` at :data:`PNG_DPI`: 1600 x 900 px); where a slide shows the
exact motion, the truth is drawn on top of the schemes (:data:`TRUTH_STYLE`, highest z-order, first in
the legend, ``gid="truth"``).  Every number a page prints comes with a sentence saying what it is.
The pages' text is in ``templates/<demo>.md`` beside this module (str.format templates, package
data), so a lecturer edits the prose without touching the code that computes its numbers.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot state, no display);
matplotlib is imported inside the functions so ``import freebody.tools.demo`` stays light.  The
Jupyter lessons in ``examples/`` (docs/teaching.md) teach the same material step by step.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import tolerances as tol
from ..adapters.base import REFERENCE_ENGINE
from ..input.casefile import load_case
from ..reference_impl.conventions import Trajectory, angular_velocity_body_from_world
from ..reference_impl.integrators import INTEGRATORS, simulate
from ..reference_impl.problem import Body, Problem
from ..reference_impl.rotations import geodesic_angle, matrix_from_quat
from ..reference_impl.truth import truth_trajectory
from ..results.io import check_output_file, write_text_atomic

DEMOS = ("integrators", "quiz", "dzhanibekov")
# The pages' text: one str.format template per demo, ``templates/<demo>.md`` beside this module
# (package data), filled by _page with the numbers of the run.
TEMPLATES = "templates"

# The lecture's schemes, in the order they are taught, with one colour each on every slide.
LECTURE_SCHEMES = ("euler-matrix", "euler-matrix-gs", "euler-quat", "lie-euler",
                   "symplectic-splitting", "implicit-midpoint", "rk4")
SCHEME_COLORS = {"euler-matrix": "#d62728", "euler-matrix-gs": "#ff7f0e", "euler-quat": "#9467bd",
                 "lie-euler": "#1f77b4", "symplectic-splitting": "#8c564b",
                 "implicit-midpoint": "#17becf", "rk4": "#2ca02c"}
# Torque-free, euler-quat and lie-euler are both an explicit Euler step on the rotations
# (see reference_impl.integrators) and nearly coincide: dashed so that both stay visible.
SCHEME_STYLES = {"lie-euler": (0, (4, 3))}
# The schemes of the zoomed lower panel of the energy figure: the bounded ones, on their own scale.
# (implicit-midpoint keeps the energy to its solver's tolerance: a flat line at 0)
ENERGY_ZOOM_SCHEMES = ("symplectic-splitting", "implicit-midpoint", "rk4")

# Integrators demo: the bundled long_horizon body (I = diag(1, 2, 3), tumbling about the major axis).
INTEGRATORS_CASE = "long_horizon"
INTEGRATORS_DT = 0.01  # s: coarse enough that the first-order schemes' errors are plain to see
INTEGRATORS_DURATION = 20.0  # s
CONVERGENCE_DURATION = 2.0  # s: short enough that explicit Euler's error (< 0.2 rad) has not saturated
CONVERGENCE_DTS = (0.1, 0.05, 0.025, 0.0125, 0.00625, 0.003125)  # s
# Why euler-matrix-gs fits a slope above 1 (gram_schmidt_one_step): one step this short measures
# the one-step error's h^2 coefficient to about 1% (0.168 against the predicted 1/6 on long_horizon)
GS_ONE_STEP_DT = 1e-3  # s
# ...and a body like long_horizon's but without I1 + I2 = I3, where Gram-Schmidt's h^2 turn does not
# cancel explicit Euler's (kg m^2, principal moments; same initial state).
GS_CONTRAST_INERTIA = (1.0, 2.0, 2.5)

# Quiz demo: the quiz case at the lecture's step.
QUIZ_CASE = "quiz"
QUIZ_DT = 0.1  # s
# An engine's quiz answer names its map when its x2 is within this of 1, 2 or 1.5 h^2 F_x / m
# (explicit, semi-implicit Euler, exact over a step): float32 engines are 1e-6 off, the maps 0.5 apart.
QUIZ_FAMILY_ATOL = 0.05

# Dzhanibekov demo.
DZHANIBEKOV_CASE = "dzhanibekov"
DZHANIBEKOV_DT = 0.01  # s
DZHANIBEKOV_DURATION = 10.0  # s
REFERENCE_IN_DZHANIBEKOV = ("euler-quat", "symplectic-splitting", "rk4")  # the reference's lines beside the engines'
# A run's flip counts as on time within this of the truth's: at dt = 0.01 s the engines'
# first-order maps flip 0.03 s late or early, explicit Euler's return flip comes seconds early.
FLIP_ON_TIME_S = 0.1
GIF_FRAMES = 80
GIF_FPS = 10
GIF_SIZE_IN = (9.6, 5.4)  # inches: 16:9, 960 x 540 px at GIF_DPI
GIF_DPI = 100

SLIDE_RC = {"font.size": 16, "axes.titlesize": 18, "axes.labelsize": 16, "legend.fontsize": 12,
            "xtick.labelsize": 14, "ytick.labelsize": 14, "lines.linewidth": 2.2,
            "axes.grid": True, "grid.alpha": 0.3, "svg.hashsalt": "freebody", "figure.dpi": 100}
SLIDE_SIZE_IN = (12.8, 7.2)  # inches: 16:9
PNG_DPI = 125  # SLIDE_SIZE_IN at this dpi: 1600 x 900 px
# The exact motion on every slide: black, dashed (the schemes that match it show through the gaps),
# drawn first (first in the legend) but on top: z-order above lines (2) and bars (1), below the
# legend (5).
TRUTH_ZORDER = 4
TRUTH_STYLE = {"color": "black", "linestyle": (0, (6, 3)), "linewidth": 2.4, "zorder": TRUTH_ZORDER}
TRUTH_GID = "truth"


@dataclass
class DemoOutput:
    """What one demo wrote: figure stems (each .png and .svg), other files, the Markdown page, facts."""

    name: str
    page: Path
    figures: list[Path] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    facts: dict = field(default_factory=dict)


def run_demo(name: str, out_dir: Path, engines: list[str] | None = None, log=None) -> DemoOutput:
    """Run one demo by name (see :data:`DEMOS`) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if name == "integrators":
        return demo_integrators(out_dir)
    if name == "quiz":
        return demo_quiz(out_dir, engines, log=log)
    if name == "dzhanibekov":
        return demo_dzhanibekov(out_dir, engines, log=log)
    raise ValueError(f"unknown demo {name!r}; known: {', '.join(DEMOS)}")


# --- drawing helpers ----------------------------------------------------------------------------

def _figure(nrows: int = 1, ncols: int = 1, size=SLIDE_SIZE_IN, **kw):
    """A figure (16:9 unless ``size`` says otherwise) on an Agg canvas (no pyplot) and its axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return fig, axes


def _save(fig, out_dir: Path, stem: str) -> Path:
    """Save ``stem``.png and ``stem``.svg (reproducible: no dates in the metadata); returns the stem path."""
    base = Path(out_dir) / stem
    for suffix in (".png", ".svg"):  # the rule for every file freebody writes (results.io)
        check_output_file(base.with_suffix(suffix))
    fig.savefig(base.with_suffix(".png"), dpi=PNG_DPI, metadata={"Software": None})
    fig.savefig(base.with_suffix(".svg"), metadata={"Date": None})
    return base


def _truth_line(ax, x, y, label: str = "truth"):
    """The exact motion's curve in :data:`TRUTH_STYLE`; call it before the schemes' lines so that the
    legend lists it first (its z-order puts it on top all the same)."""
    (line,) = ax.plot(x, y, label=label, gid=TRUTH_GID, **TRUTH_STYLE)
    return line


def _truth_hline(ax, y: float, label: str = "truth"):
    """A horizontal truth line (e.g. the conserved energy's zero error) in :data:`TRUTH_STYLE`."""
    return ax.axhline(y, label=label, gid=TRUTH_GID, **TRUTH_STYLE)


def _rc():
    import matplotlib

    return matplotlib.rc_context(SLIDE_RC)


def _write_page(path: Path, text: str) -> Path:
    write_text_atomic(path, text.strip() + "\n")
    return path


@functools.lru_cache(maxsize=None)
def _template(name: str) -> str:
    """The text of the page template ``templates/<name>.md`` (package data of freebody.tools)."""
    return (importlib.resources.files(__package__) / TEMPLATES / f"{name}.md").read_text(encoding="utf-8")


def _page(name: str, **fields) -> str:
    """A demo page: its template (:data:`TEMPLATES`) filled by ``str.format`` with ``fields``, the
    values the template names (``{dt:g}``, ``{final[rk4][energy_max]:.1e}``, ...)."""
    return _template(name).format(**fields)


def _signed_energy_error(problem: Problem, tr: Trajectory) -> np.ndarray:
    """(E(t) - E(0)) / KE(0), shape (N,): the energy error relative to the initial kinetic energy,
    signed (positive: the scheme has gained energy)."""
    from ..run.metrics import energies

    ke, E = energies(problem, tr)
    return (E - E[0]) / ke[0]


def _with(problem: Problem, duration: float, dt: float) -> Problem:
    return dataclasses.replace(problem, duration=duration, duration_steps=None, dts=(dt,))


def _gains(e: float) -> str:
    """'gains' or 'loses' for a signed energy error."""
    return "gains" if e > 0 else "loses"


# --- integrators ------------------------------------------------------------------------------

def integrators_data(problem: Problem, dt: float, duration: float) -> dict:
    """Per lecture scheme: t (N,) s, the signed energy error (E(t) - E(0)) / KE(0) (N,), the
    orientation error (N,) rad against the closed-form truth, and for the matrix schemes the
    orthonormality error ||R^T R - 1||_F (N,); samples after a blow-up are NaN."""
    steps = int(round(duration / dt))
    truth = truth_trajectory(problem, dt, steps)
    out = {}
    for name in LECTURE_SCHEMES:
        tr = simulate(problem, name, dt, steps)
        finite = np.all(np.isfinite(tr.quaternion_wxyz), axis=1)
        out[name] = {"t": tr.t, "energy": np.where(finite, _signed_energy_error(problem, tr), np.nan),
                     "orientation": geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz),
                     "orthonormality": tr.orthonormality_error}
    return out


def convergence_data(problem: Problem, duration: float, dts=CONVERGENCE_DTS,
                     names=LECTURE_SCHEMES) -> dict:
    """Per scheme of ``names``: the max orientation error (rad) over [0, duration] at each dt, the
    least-squares slope of log(error) against log(dt) over the errors in
    tol.DEMO_SLOPE_FIT_RANGE_RAD, the local slopes log2(e(dt_i) / e(dt_i+1)) / log2(dt_i / dt_i+1)
    between neighbouring steps (len(dts) - 1), and error / dt at the finest step (rad/s: the
    first-order coefficient, once the local slopes have settled at 1)."""
    out = {}
    dt_arr = np.array(dts, dtype=float)
    for name in names:
        errs = []
        for dt in dts:
            steps = int(round(duration / dt))
            tr = simulate(problem, name, dt, steps)
            truth = truth_trajectory(problem, dt, steps)
            errs.append(float(np.max(geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz))))
        errs = np.array(errs)
        lo, hi = tol.DEMO_SLOPE_FIT_RANGE_RAD
        use = (errs > lo) & (errs < hi)
        slope = float(np.polyfit(np.log(dt_arr[use]), np.log(errs[use]), 1)[0]) if use.sum() >= 2 else None
        with np.errstate(divide="ignore", invalid="ignore"):
            local = np.log(errs[:-1] / errs[1:]) / np.log(dt_arr[:-1] / dt_arr[1:])
        out[name] = {"dt": list(dts), "error": errs.tolist(), "slope": slope, "order": INTEGRATORS[name].order,
                     "fitted": use.tolist(), "local_slopes": local.tolist(),
                     "error_per_dt": float(errs[-1] / dt_arr[-1])}
    return out


def gram_schmidt_one_step(problem: Problem, h: float = GS_ONE_STEP_DT) -> dict:
    """Why ``euler-matrix-gs`` has a small first-order error on some bodies: its one-step
    orientation error from the initial state, measured and predicted, beside ``lie-euler``'s.

    One step of explicit Euler on the rotations with w frozen misses the exact motion's
    h^2/2 dw/dt (Magnus); Gram-Schmidt after R + h [w] R turns R by a further -h^2 k, with
    k_b = (w_y w_z, -w_x w_z, w_x w_y) / 2 in the body frame (from the Cholesky factor of
    R^T R = 1 + h^2 (|w|^2 - w_b w_b^T)).  So the one-step errors are h^2 |dw_b/dt| / 2 (lie-euler)
    and h^2 |dw_b/dt / 2 + k_b| (euler-matrix-gs), dw_b/dt from Euler's equations.  Returns the
    measured angle / h^2 and the predicted coefficient for both (rad/s^2), and w_b (3,) rad/s,
    dw_b/dt (3,) rad/s^2, k_b (3,) 1/s^2 at t = 0, body frame.
    """
    truth = truth_trajectory(problem, h, 1)
    measured = {name: float(geodesic_angle(truth.quaternion_wxyz[1],
                                           simulate(problem, name, h, 1).quaternion_wxyz[1])) / h ** 2
                for name in ("euler-matrix-gs", "lie-euler")}
    I_b = problem.body.I_body
    w_b = problem.R0.T @ np.asarray(problem.initial.angular_velocity, dtype=float)
    wdot_b = problem.body.I_body_inv @ -np.cross(w_b, I_b @ w_b)
    k_b = 0.5 * np.array([w_b[1] * w_b[2], -w_b[0] * w_b[2], w_b[0] * w_b[1]])
    predicted = {"lie-euler": float(np.linalg.norm(wdot_b) / 2),
                 "euler-matrix-gs": float(np.linalg.norm(wdot_b / 2 + k_b))}
    return {"h": h, "measured": measured, "predicted": predicted, "w_b": w_b.tolist(),
            "wdot_b": wdot_b.tolist(), "k_b": k_b.tolist()}


def _with_inertia(problem: Problem, moments) -> Problem:
    """The same problem with a diagonal body inertia diag(moments), kg m^2."""
    return dataclasses.replace(problem, body=Body(problem.body.mass, np.diag(np.asarray(moments, dtype=float))))


def demo_integrators(out_dir: Path, dt: float = INTEGRATORS_DT, duration: float = INTEGRATORS_DURATION,
                     convergence_duration: float = CONVERGENCE_DURATION,
                     convergence_dts=CONVERGENCE_DTS) -> DemoOutput:
    """Four figures and ``integrators.md``."""
    base = load_case(INTEGRATORS_CASE)
    problem = _with(base, duration, dt)
    data = integrators_data(problem, dt, duration)
    conv_problem = _with(base, convergence_duration, dt)
    conv = convergence_data(conv_problem, convergence_duration, convergence_dts)
    contrast = convergence_data(_with_inertia(conv_problem, GS_CONTRAST_INERTIA), convergence_duration,
                                convergence_dts, names=("euler-matrix-gs",))["euler-matrix-gs"]
    gs_step = gram_schmidt_one_step(base)
    res = DemoOutput("integrators", out_dir / "integrators.md")
    with _rc():
        res.figures.extend(_plot_integrator_errors(data, dt, out_dir))
        res.figures.append(_plot_orthonormality(data, out_dir))
        res.figures.append(_plot_convergence(conv, convergence_duration, out_dir))

    steps = int(round(duration / dt))
    final = {n: {"energy": _nanlast(data[n]["energy"]), "orientation": _nanlast(data[n]["orientation"]),
                 "energy_max": float(np.nanmax(np.abs(data[n]["energy"]))),
                 "energy_min_signed": float(np.nanmin(data[n]["energy"])),
                 "energy_max_signed": float(np.nanmax(data[n]["energy"]))} for n in LECTURE_SCHEMES}
    ortho = float(data["euler-matrix"]["orthonormality"][-1])
    res.facts = {"slopes": {n: conv[n]["slope"] for n in LECTURE_SCHEMES}, "final": final,
                 "orthonormality_final": ortho, "convergence": conv,
                 "gram_schmidt": {"one_step": gs_step, "contrast_inertia": list(GS_CONTRAST_INERTIA),
                                  "contrast_slope": contrast["slope"],
                                  "contrast_error_per_dt": contrast["error_per_dt"]}}
    _write_page(res.page, _integrators_page(dt, duration, steps, convergence_duration, final, conv, ortho,
                                            gs_step, contrast))
    return res


def _plot_integrator_errors(data: dict, dt: float, out_dir: Path) -> list[Path]:
    """The signed energy-error figure (linear, all schemes above, the bounded ones zoomed below, the
    exact energy's zero line on top) and the orientation-error figure (log scale) of integrators_data."""
    fig, axes = _figure(2, 1, sharex=True)
    ax_all, ax_zoom = axes[:, 0]
    for ax, names in ((ax_all, LECTURE_SCHEMES), (ax_zoom, ENERGY_ZOOM_SCHEMES)):
        _truth_hline(ax, 0.0, label="truth: E conserved")
        for name in names:
            ax.plot(data[name]["t"], data[name]["energy"], color=SCHEME_COLORS[name], label=name,
                    linestyle=SCHEME_STYLES.get(name, "-"))
    ax_all.set(ylabel="(E(t) - E(0)) / KE(0)",
               title=f"Energy error, signed: explicit Euler gains energy (tumbling body, dt = {dt:g} s)")
    ax_zoom.set(xlabel="t (s)", ylabel="(E(t) - E(0)) / KE(0)",
                title="Zoom: the splitting's error oscillates, bounded; the implicit midpoint's stays at 0")
    ax_all.legend(loc="upper left", ncols=2, fontsize=11)
    ax_zoom.legend(loc="upper left", ncols=4, fontsize=11)
    stems = [_save(fig, out_dir, "integrators_energy")]

    fig, ax = _figure()
    ax = ax[0, 0]
    for name in LECTURE_SCHEMES:
        y = np.maximum(data[name]["orientation"][1:], 1e-17)  # t = 0 (zero error) off the log axis
        ax.semilogy(data[name]["t"][1:], y, color=SCHEME_COLORS[name], label=name,
                    linestyle=SCHEME_STYLES.get(name, "-"))
    ax.set(xlabel="t (s)", ylabel="orientation error (rad)",
           title=f"Orientation error against the exact motion, dt = {dt:g} s")
    ax.legend(loc="lower right", ncols=2)
    stems.append(_save(fig, out_dir, "integrators_orientation"))
    return stems


def _plot_orthonormality(data: dict, out_dir: Path) -> Path:
    """||R^T R - 1||_F against t for the matrix schemes, with and without Gram-Schmidt."""
    fig, ax = _figure()
    ax = ax[0, 0]
    for name in ("euler-matrix", "euler-matrix-gs"):
        y = np.maximum(data[name]["orthonormality"][1:], 1e-17)
        ax.semilogy(data[name]["t"][1:], y, color=SCHEME_COLORS[name], label=name)
    ax.set(xlabel="t (s)", ylabel=r"$\|R^T R - 1\|_F$",
           title="R stops being a rotation without Gram-Schmidt")
    ax.legend(loc="center right")
    return _save(fig, out_dir, "integrators_orthonormality")


def _plot_convergence(conv: dict, convergence_duration: float, out_dir: Path) -> Path:
    """Max orientation error against dt (log-log) per scheme of convergence_data, slopes in the legend."""
    fig, ax = _figure()
    ax = ax[0, 0]
    for name in LECTURE_SCHEMES:
        c = conv[name]
        ax.loglog(c["dt"], c["error"], marker="o", color=SCHEME_COLORS[name],
                  linestyle=SCHEME_STYLES.get(name, "-"), label=f"{name}: slope {_fmt_slope(c['slope'])}")
    ax.set(xlabel="dt (s)", ylabel="max orientation error (rad)",
           title=f"Convergence over {convergence_duration:g} s: the slope is the observed order")
    ax.legend(loc="lower right", fontsize=11)
    return _save(fig, out_dir, "integrators_convergence")


def _local_slopes(c: dict) -> str:
    return ", ".join(f"{s:.2f}" for s in c["local_slopes"])


def _integrators_page(dt: float, duration: float, steps: int, convergence_duration: float, final: dict,
                      conv: dict, ortho: float, gs_step: dict, contrast: dict) -> str:
    """The Markdown of ``integrators.md``: ``final`` and ``conv`` as in demo_integrators' facts,
    ``ortho`` the final orthonormality error of euler-matrix, ``gs_step`` from gram_schmidt_one_step,
    ``contrast`` euler-matrix-gs's convergence_data on the GS_CONTRAST_INERTIA body."""
    rows = "\n".join(f"| `{n}` | {INTEGRATORS[n].summary} | {final[n]['energy']:+.2e} | "
                     f"{final[n]['orientation']:.2e} | {_fmt_slope(conv[n]['slope'])} |"
                     for n in LECTURE_SCHEMES)
    readings = "\n".join(
        f"- `{n}` {_gains(final[n]['energy'])} {abs(final[n]['energy']):.2g} of its initial kinetic "
        f"energy in {duration:g} s ({final[n]['energy']:+.2e}) and ends {final[n]['orientation']:.2g} rad "
        f"from the true orientation; its error shrinks with dt at the fitted slope "
        f"{_fmt_slope(conv[n]['slope'])} (formal order {INTEGRATORS[n].order})."
        for n in LECTURE_SCHEMES)
    split, mid = final["symplectic-splitting"], final["implicit-midpoint"]
    em, eq, gs = final["euler-matrix"], final["euler-quat"], final["euler-matrix-gs"]
    cg, cq = conv["euler-matrix-gs"], conv["euler-quat"]
    dt0, e0 = cg["dt"][0], cg["error"][0]
    a_gs = cg["error_per_dt"]
    share = max(0.0, (e0 - a_gs * dt0) / e0)
    cm = conv["euler-matrix"]
    left_out = [f"{d:g} s ({e:.2g} rad)" for d, e, u in zip(cm["dt"], cm["error"], cm["fitted"]) if not u]
    left_out_text = (f" `euler-matrix`'s error at dt = {', '.join(left_out)} is above the fit range "
                     f"({tol.DEMO_SLOPE_FIT_RANGE_RAD[1]:g} rad) and left out of its fit." if left_out else "")
    m, p = gs_step["measured"], gs_step["predicted"]
    return _page("integrators", case=INTEGRATORS_CASE, steps=steps, dt=dt, duration=duration, rows=rows,
                 readings=readings, final=final, em=em, eq=eq, gs=gs, split=split, mid=mid, ortho=ortho,
                 convergence_duration=convergence_duration, left_out_text=left_out_text, cq=cq,
                 quat_local_slopes=_local_slopes(cq), gs_slope=_fmt_slope(cg["slope"]),
                 gs_local_slopes=_local_slopes(cg), a_gs=a_gs, quat_over_gs=cq["error_per_dt"] / a_gs,
                 dt0=dt0, share=share, e0=e0, gs_step=gs_step, m=m, p=p,
                 contrast_inertia=tuple(GS_CONTRAST_INERTIA), contrast=contrast,
                 contrast_slope=_fmt_slope(contrast["slope"]))


def _nanlast(a: np.ndarray) -> float:
    finite = np.flatnonzero(np.isfinite(a))
    return float(a[finite[-1]]) if finite.size else float("nan")


def _fmt_slope(s) -> str:
    return "-" if s is None else f"{s:.2f}"


# --- quiz ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class QuizRow:
    """One scheme's state at t2 = 2h.

    x2 : (3,) m, COM, world.  angle2 : rad, rotation about world z of the (nearest) rotation.
    v2 : (3,) m/s.  w2 : (3,) rad/s, world.  status : "ok" or why there is no row.
    """

    label: str
    family: str
    x2: np.ndarray | None
    angle2: float | None
    v2: np.ndarray | None
    w2: np.ndarray | None
    status: str = "ok"


def quiz_closed_form(problem: Problem, h: float) -> dict:
    """Explicit Euler on (x, R, P, L) at t2 = 2h for the quiz, in closed form.

    The push F at the world point r acts on the first step only, from rest at the origin, with
    I = I_b (a sphere) and R0 = 1:  x2 = h^2 (F/m + g);  R2 = 1 + h [w1] with w1 = I^-1 (r x F) h;
    P2 = h F + 2 h m g;  L2 = h (r x F).  Returns those arrays (x2 (3,), R2 (3, 3), P2 (3,), L2 (3,),
    w1 (3,)) and the force, torque, mass and gravity used.
    """
    from ..reference_impl.rotations import skew

    load = problem.loads[0]
    m, g, I_inv = problem.body.mass, problem.gravity, problem.body.I_body_inv
    F = np.asarray(load.force)
    tau = np.cross(np.asarray(load.point) - problem.initial.position, F)
    w1 = I_inv @ (h * tau)
    return {"x2": h * h * (F / m + g), "R2": np.eye(3) + h * skew(w1), "P2": h * F + 2 * h * m * g,
            "L2": h * tau, "w1": w1, "F": F, "tau": tau, "m": m, "g": np.asarray(g)}


def _angle_z(q: np.ndarray) -> float:
    """Signed rotation angle about world z (rad) of a rotation that is about z, from (w, x, y, z)."""
    return float(2.0 * np.arctan2(q[3], q[0]))


def quiz_family(x2_x: float, h: float, cf: dict) -> str:
    """The map an engine's quiz answer shows, from the COM's x at t2 in units of h^2 F_x / m:
    1 explicit Euler, 2 semi-implicit Euler, 1.5 a force held over the step integrated exactly
    (RK4 and higher), anything else "other" (within QUIZ_FAMILY_ATOL of those units)."""
    u = x2_x / (h * h * cf["F"][0] / cf["m"])
    for family, value in (("explicit", 1.0), ("semi-implicit", 2.0), ("rk4", 1.5)):
        if abs(u - value) < QUIZ_FAMILY_ATOL:
            return family
    return "other"


def quiz_rows(problem: Problem, h: float, engines: list[str] | None, log=None) -> list[QuizRow]:
    """The quiz at t2 for the closed form, the reference schemes, every installed engine's
    integrators at the engine's first precision (missing or failing engines as rows with their
    status; each engine row's family from its answer, :func:`quiz_family`), and the truth."""
    from ..run import RunSpec, engine_integrators, execute, select_engines

    cf = quiz_closed_form(problem, h)
    m = cf["m"]
    rows = [QuizRow("explicit Euler, closed form", "explicit", cf["x2"],
                    float(np.arctan2(cf["R2"][1, 0], cf["R2"][0, 0])), cf["P2"] / m,
                    problem.body.I_body_inv @ cf["L2"])]
    for name, family in (("euler-matrix", "explicit"), ("semi-implicit-explicit-gyro", "semi-implicit"),
                         ("rk4", "rk4")):
        tr = simulate(problem, name, h, 2)
        rows.append(QuizRow(f"reference {name}", family, tr.position[2], _angle_z(tr.quaternion_wxyz[2]),
                            tr.linear_velocity[2], tr.angular_velocity[2]))
    for engine in select_engines(engines):
        if engine == REFERENCE_ENGINE:  # its maps are the rows above
            continue
        offered = engine_integrators(engine)
        if offered is None:
            spec = RunSpec(problem, engine, "*", h, 2)
            r = execute(spec, identify_scheme=False).result
            rows.append(QuizRow(f"{engine}", "missing", None, None, None, None, f"{r.status}: {r.message}"))
            continue
        precision = _engine_precision(engine)
        for integ in offered:
            if log:
                log(f"quiz: {engine}/{integ}")
            out = execute(RunSpec(problem, engine, integ, h, 2, precision), identify_scheme=False)
            tr = out.trajectory
            label = f"{engine} {integ}" + ("" if precision == "float64" else f" ({precision})")
            if tr is None or len(tr) < 3:
                rows.append(QuizRow(label, "missing", None, None, None, None,
                                    f"{out.result.status}: {out.result.message}"))
                continue
            rows.append(QuizRow(label, quiz_family(tr.position[2][0], h, cf), tr.position[2],
                                _angle_z(tr.quaternion_wxyz[2]), tr.linear_velocity[2], tr.angular_velocity[2]))
    truth = truth_trajectory(problem, h, 2)
    rows.append(QuizRow("truth (DOP853)", "truth", truth.position[2], _angle_z(truth.quaternion_wxyz[2]),
                        truth.linear_velocity[2], truth.angular_velocity[2]))
    return rows


# the truth row's bar is light grey so that the truth's dashed black line shows on top of it
FAMILY_COLORS = {"explicit": "#d62728", "semi-implicit": "#1f77b4", "rk4": "#2ca02c", "other": "#9467bd",
                 "truth": "#bbbbbb"}


def demo_quiz(out_dir: Path, engines: list[str] | None = None, h: float = QUIZ_DT, log=None) -> DemoOutput:
    """The push quiz at t2: one figure (x2 and the rotation angle per scheme) and ``quiz.md``."""
    problem = load_case(QUIZ_CASE)
    cf = quiz_closed_form(problem, h)
    rows = quiz_rows(problem, h, engines, log=log)
    res = DemoOutput("quiz", out_dir / "quiz.md")
    drawn = [r for r in rows if r.status == "ok"]
    with _rc():
        res.figures.append(_plot_quiz(drawn, rows[-1], h, out_dir))

    table = "\n".join(
        f"| {r.label} | {_vec(r.x2)} | {np.degrees(r.angle2):.4g} | {_vec(r.v2)} | {_vec(r.w2)} |"
        if r.status == "ok" else f"| {r.label} | {r.status} | | | |" for r in rows)
    x_ratio = {r.label: r.x2[0] / (h * h * cf["F"][0] / cf["m"]) for r in drawn}
    res.facts = {"closed_form": {k: np.asarray(val).tolist() for k, val in cf.items()},
                 "rows": [{"label": r.label, "family": r.family, "status": r.status,
                           "x2": None if r.x2 is None else r.x2.tolist(), "angle2": r.angle2} for r in rows],
                 "x_over_h2F": x_ratio}
    _write_page(res.page, _quiz_page(cf, h, table, _quiz_readings(rows, h, cf)))
    return res


def _quiz_readings(rows: list[QuizRow], h: float, cf: dict) -> str:
    """One sentence per row of the quiz table: its numbers, and its x and angle against the truth's
    (the last row) in units of h^2 F_x / m and h^2."""
    truth = rows[-1]
    unit_x = h * h * cf["F"][0] / cf["m"]
    out = []
    for r in rows:
        if r.status != "ok":
            out.append(f"- **{r.label}** has no numbers: {r.status}.")
            continue
        out.append(
            f"- **{r.label}** puts the COM at x2 = {_vec(r.x2)} m (x = {r.x2[0] / unit_x:.3g} h^2 F_x/m, the "
            f"truth's {truth.x2[0] / unit_x:.3g}; z = {r.x2[2] / (h * h * cf['g'][2]):.3g} h^2 g_z) and turns "
            f"the body by {np.degrees(r.angle2):.4g} deg about z ({r.angle2 / h ** 2:.3g} h^2 rad); it moves on "
            f"at v2 = {_vec(r.v2)} m/s and turns at w2 = {_vec(r.w2)} rad/s.")
    return "\n".join(out)


def _vec(a) -> str:
    """A vector as "(x, y, z)" with 4 significant digits."""
    return "(" + ", ".join(f"{x:.4g}" for x in a) + ")"


def _plot_quiz(drawn: list[QuizRow], truth: QuizRow, h: float, out_dir: Path) -> Path:
    """Bars of x2 and of the rotation angle at t2 per drawn row, coloured by family, the truth's
    values as dashed lines on top."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    fig, axes = _figure(1, 2, sharey=True)
    labels = [r.label for r in drawn][::-1]
    ypos = np.arange(len(labels))
    for ax, values, exact, xlabel in (
            (axes[0, 0], [r.x2[0] * 100 for r in drawn][::-1], truth.x2[0] * 100, "x2, x component (cm)"),
            (axes[0, 1], [np.degrees(r.angle2) for r in drawn][::-1], np.degrees(truth.angle2),
             "rotation about z at t2 (deg)")):
        ax.axvline(exact, gid=TRUTH_GID, **TRUTH_STYLE)
        colors = [FAMILY_COLORS[r.family] for r in drawn][::-1]
        ax.barh(ypos, values, color=colors)
        ax.set_xlabel(xlabel)
        ax.grid(axis="y", visible=False)
    axes[0, 0].set_yticks(ypos, labels)
    # every engine's every integrator: smaller labels when there are many rows (about 560 px of them)
    axes[0, 0].tick_params(axis="y", labelsize=max(7.0, min(14.0, 28.0 * 14 / max(len(labels), 1) / 2)))
    present = [f for f in dict.fromkeys(r.family for r in drawn) if f != "truth"]
    names = {"explicit": "explicit Euler", "semi-implicit": "semi-implicit Euler (engines' map)",
             "rk4": "RK4 (force integrated exactly)", "other": "another map"}
    handles = [Line2D([], [], label="truth (exact motion)", **TRUTH_STYLE)]
    handles += [Patch(color=FAMILY_COLORS[f], label=names[f]) for f in present]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles) if len(handles) <= 4 else 3,
               fontsize=12)
    fig.suptitle(f"The push quiz after two steps of h = {h:g} s (dashed: the exact motion)")
    return _save(fig, out_dir, "quiz_t2")


def _quiz_page(cf: dict, h: float, table: str, readings: str) -> str:
    """The Markdown of ``quiz.md``: ``cf`` from quiz_closed_form, ``table`` the table body,
    ``readings`` a sentence per row (_quiz_readings)."""
    F, tau, g, m = cf["F"], cf["tau"], cf["g"], cf["m"]
    return _page("quiz", m=m, h=h, g_vec=_vec(g), F_vec=_vec(F), tau_vec=_vec(tau), x2_vec=_vec(cf["x2"]),
                 w1_vec=_vec(cf["w1"]), P2_vec=_vec(cf["P2"]), L2_vec=_vec(cf["L2"]),
                 det_R2=np.linalg.det(cf["R2"]), table=table, unit_x=h * h * F[0] / m, unit_z=h * h * g[2],
                 readings=readings)


# --- dzhanibekov --------------------------------------------------------------------------------

def dzhanibekov_runs(problem: Problem, dt: float, steps: int, engines: list[str] | None, log=None):
    """(label, trajectory or None, status message) per engine integrator, the reference's
    REFERENCE_IN_DZHANIBEKOV first; a missing or failing engine has no trajectory and says why."""
    from ..run import RunSpec, Status, TruthCache, engine_integrators, execute, select_engines

    cache = TruthCache()
    out = []
    for engine in select_engines(engines):
        offered = engine_integrators(engine)
        chosen = REFERENCE_IN_DZHANIBEKOV if engine == REFERENCE_ENGINE else (offered or ("*",))
        precision = _engine_precision(engine)
        for integ in chosen:
            if log:
                log(f"dzhanibekov: {engine}/{integ}")
            r = execute(RunSpec(problem, engine, integ, dt, steps, precision), cache, identify_scheme=False)
            ok = r.trajectory is not None and r.result.status == Status.OK
            label = (f"{engine}/{integ}" if integ != "*" else engine) + (
                "" if precision == "float64" else f" ({precision})")
            out.append((label, r.trajectory if ok else None,
                        Status.OK.value if ok else f"{r.result.status}: {r.result.message}"))
    return out


def _engine_precision(engine: str) -> str:
    """float64 when the engine offers it, else its first precision (float32 engines)."""
    from ..run import engine_precisions

    offered = engine_precisions(engine) or ("float64",)
    return "float64" if "float64" in offered else offered[0]


def demo_dzhanibekov(out_dir: Path, engines: list[str] | None = None, dt: float = DZHANIBEKOV_DT,
                     duration: float = DZHANIBEKOV_DURATION, frames: int = GIF_FRAMES, log=None) -> DemoOutput:
    """Angular velocity (body and world) and signed energy error per engine, each run's flip times
    against the truth's, a GIF, ``dzhanibekov.md``."""
    problem = _with(load_case(DZHANIBEKOV_CASE), duration, dt)
    steps = int(round(duration / dt))
    truth = truth_trajectory(problem, dt, steps)
    runs = dzhanibekov_runs(problem, dt, steps, engines, log=log)
    res = DemoOutput("dzhanibekov", out_dir / "dzhanibekov.md")
    wb_true = angular_velocity_body_from_world(truth.quaternion_wxyz, truth.angular_velocity)
    with _rc():
        res.figures.append(_plot_dzhanibekov(problem, truth, wb_true, runs, out_dir))
        gif = out_dir / "dzhanibekov.gif"
        animate_box(problem, truth, gif, frames)
        res.files.append(gif)

    flips = _flip_times(truth.t, wb_true[:, 1])
    s_truth = separatrix_distance(problem, truth)
    stats = []
    for lab, tr, st in runs:
        if tr is None:
            continue
        e = _signed_energy_error(problem, tr)
        wb = angular_velocity_body_from_world(tr.quaternion_wxyz, tr.angular_velocity)
        stats.append({"label": lab, "energy_extreme": float(e[np.nanargmax(np.abs(e))]),
                      "orientation_max": float(np.max(geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz))),
                      "flips": _flip_times(tr.t, wb[:, 1]),
                      "separatrix_end": float(separatrix_distance(problem, tr)[-1])})
    for st in stats:
        st["flips_on_time"] = _flips_on_time(st["flips"], flips)
    res.facts = {"flip_times_s": flips, "runs": [{"label": lab, "status": st} for lab, _, st in runs],
                 "run_stats": stats, "separatrix_truth": float(s_truth[0])}
    missing = "\n".join(f"- {lab}: {st}" for lab, tr, st in runs if tr is None) or "- none"
    finals = "\n".join(f"| {st['label']} | {st['energy_extreme']:+.2e} | {st['orientation_max']:.3g} | "
                       f"{st['separatrix_end']:+.1e} | {_times(st['flips'])} |" for st in stats)
    readings = "\n".join(_dzhanibekov_reading(st, flips, duration, float(s_truth[0])) for st in stats)
    _write_page(res.page, _dzhanibekov_page(dt, duration, flips, float(s_truth[0]), finals, readings, missing,
                                            frames))
    return res


def separatrix_distance(problem: Problem, tr: Trajectory) -> np.ndarray:
    """s = 2 E I2 / |L|^2 - 1, shape (N,): how far the motion is from the separatrix, the motion
    that approaches the intermediate axis forever (I2 the intermediate principal moment; E and |L|
    of the trajectory's own samples).  s > 0: the body's axis circulates about the minor axis,
    s < 0: about the major axis; the time between flips grows like log(1 / |s|)."""
    I_b = problem.body.I_body
    wb = angular_velocity_body_from_world(tr.quaternion_wxyz, tr.angular_velocity)
    m = wb @ I_b.T  # body-frame angular momentum, kg m^2/s
    two_E = np.einsum("ni,ni->n", wb, m)
    I2 = np.linalg.eigvalsh(I_b)[1]
    return two_E * I2 / np.einsum("ni,ni->n", m, m) - 1.0


def _times(ts: list[float]) -> str:
    return ", ".join(f"{t:.2f}" for t in ts) or "none"


def _hold(flips: list[float]) -> str:
    """The truth's time between its first two flips, as words."""
    return f"{flips[1] - flips[0]:.2f} s between its flips" if len(flips) > 1 else "longer than this run"


def _flips_on_time(flips: list[float], truth_flips: list[float]) -> int:
    """How many of a run's flips, from the first on, come within FLIP_ON_TIME_S of the truth's."""
    n = 0
    for a, b in zip(flips, truth_flips):
        if abs(a - b) > FLIP_ON_TIME_S:
            break
        n += 1
    return n


def _dzhanibekov_reading(st: dict, truth_flips: list[float], duration: float, s_truth: float) -> str:
    """One sentence for a row of the Dzhanibekov table (``st`` a run_stats entry)."""
    e, o, f, k = st["energy_extreme"], st["orientation_max"], st["flips"], st["flips_on_time"]
    upside = " (near pi rad: at times upside down against the truth)" if o > 3.0 else ""
    if not f:
        verdict = "it never flips: it misses the flip"
    elif k == len(f) == len(truth_flips):
        verdict = f"all on time (within {FLIP_ON_TIME_S:g} s of the truth's)"
    else:
        head = "none on time" if k == 0 else ("the first on time" if k == 1 else f"the first {k} on time")
        if k < len(f) and k < len(truth_flips):
            miss = f"flip {k + 1} comes {f[k] - truth_flips[k]:+.2f} s off the truth's {truth_flips[k]:.2f} s"
        elif k < len(truth_flips):
            miss = f"it misses the truth's flip at {truth_flips[k]:.2f} s"
        else:
            miss = f"then {len(f) - k} that the truth does not make"
        verdict = f"{head}; {miss}" + (f" ({len(f)} flips, the truth {len(truth_flips)})"
                                       if len(f) != len(truth_flips) else "")
    return (f"- `{st['label']}` {_gains(e)} up to {abs(e):.2g} of its energy ({e:+.2e}), strays at most "
            f"{o:.3g} rad from the true orientation{upside}, ends at s = {st['separatrix_end']:+.1e} from the "
            f"separatrix (the truth stays at {s_truth:+.1e}) and flips {len(f)} times in {duration:g} s"
            f"{f', at {_times(f)} s' if f else ''}: {verdict}.")


def _plot_dzhanibekov(problem: Problem, truth: Trajectory, wb_true: np.ndarray, runs: list,
                      out_dir: Path) -> Path:
    """Three panels against t: body-frame w_y, world-frame w_x and the signed energy error, for the
    truth (``wb_true``: its body-frame angular velocity (N, 3)), on top, and every run of
    dzhanibekov_runs that has a trajectory."""
    import matplotlib

    styles = ["-", "--", "-.", ":"]
    fig, axes = _figure(3, 1, sharex=True)
    ax_b, ax_w, ax_e = axes[:, 0]
    _truth_line(ax_b, truth.t, wb_true[:, 1])
    _truth_line(ax_w, truth.t, truth.angular_velocity[:, 0])
    _truth_hline(ax_e, 0.0)
    cmap = matplotlib.colormaps["tab10"]
    drawn = [(lab, tr) for lab, tr, _ in runs if tr is not None]
    for k, (label, tr) in enumerate(drawn):
        color, ls = cmap(k % 10), styles[k % len(styles)]
        wb = angular_velocity_body_from_world(tr.quaternion_wxyz, tr.angular_velocity)
        ax_b.plot(tr.t, wb[:, 1], color=color, linestyle=ls, label=label)
        ax_w.plot(tr.t, tr.angular_velocity[:, 0], color=color, linestyle=ls)
        ax_e.plot(tr.t, _signed_energy_error(problem, tr), color=color, linestyle=ls)
    # signed, over ten decades: linear within +-1e-10 (round-off), logarithmic beyond
    ax_e.set_yscale("symlog", linthresh=1e-10)
    ax_e.yaxis.set_major_locator(matplotlib.ticker.FixedLocator([-1e-1, -1e-6, 0.0, 1e-6, 1e-1]))
    ax_b.set(ylabel=r"$\omega_{body,y}$" "\n(rad/s)", title="The intermediate axis flips (Dzhanibekov effect)")
    ax_w.set(ylabel=r"$\omega_{world,x}$" "\n(rad/s)")
    ax_e.set(xlabel="t (s)", ylabel="(E - E0) / E0\n(symlog)")
    # the truth and every run beside the panels: one column of up to 14 entries, then more, smaller
    n = len(drawn) + 1
    fig.legend(handles=ax_b.get_lines(), loc="outside right upper", ncols=int(np.ceil(n / 20)) if n > 14 else 1,
               fontsize=11 if n <= 14 else 8)
    return _save(fig, out_dir, "dzhanibekov_flip")


def _dzhanibekov_page(dt: float, duration: float, flips: list[float], s_truth: float, finals: str,
                      readings: str, missing: str, frames: int) -> str:
    """The Markdown of ``dzhanibekov.md``: ``finals`` the table body, ``readings`` a sentence per
    row, ``missing`` the list of runs not drawn, ``frames`` the GIF's."""
    gif_w, gif_h = (round(v * GIF_DPI) for v in GIF_SIZE_IN)
    return _page("dzhanibekov", n_flips=len(flips), flip_times=_times(flips), hold=_hold(flips), dt=dt,
                 duration=duration, finals=finals, readings=readings, s_truth=s_truth, missing=missing,
                 frames=frames, fps=GIF_FPS, gif_w=gif_w, gif_h=gif_h)


def _flip_times(t: np.ndarray, wy: np.ndarray) -> list[float]:
    """Times (s) at which the body-frame intermediate-axis rate changes sign, interpolated linearly
    between the samples around each change."""
    s = np.sign(wy)
    idx = np.flatnonzero(s[1:] * s[:-1] < 0)
    return [float(t[i] - wy[i] * (t[i + 1] - t[i]) / (wy[i + 1] - wy[i])) for i in idx]


def _box_faces(size) -> np.ndarray:
    """The 6 faces of a centred box, shape (6, 4, 3), m, body frame."""
    a, b, c = np.asarray(size) / 2
    v = np.array([[x, y, z] for x in (-a, a) for y in (-b, b) for z in (-c, c)])
    idx = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return np.array([[v[i] for i in f] for f in idx])


def animate_box(problem: Problem, truth: Trajectory, path: Path, frames: int = GIF_FRAMES) -> None:
    """A 16:9 GIF (GIF_SIZE_IN at GIF_DPI) of the box tumbling along ``truth`` beside its body-frame
    w_y against t, ``frames`` frames at GIF_FPS, via PillowWriter."""
    with _rc():  # slide fonts, also when called on its own (the lesson notebook does)
        _draw_box_gif(problem, truth, path, frames)


def _draw_box_gif(problem: Problem, truth: Trajectory, path: Path, frames: int) -> None:
    from matplotlib.animation import PillowWriter
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = Figure(figsize=GIF_SIZE_IN)
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(1, 2, width_ratios=(1.0, 1.15), left=0.0, right=0.97, bottom=0.14, top=0.9,
                            wspace=0.15)
    ax = fig.add_subplot(grid[0, 0], projection="3d")
    ax_w = fig.add_subplot(grid[0, 1])
    wb = angular_velocity_body_from_world(truth.quaternion_wxyz, truth.angular_velocity)
    ax_w.plot(truth.t, wb[:, 1], color="black", linewidth=2.0)
    (dot,) = ax_w.plot([], [], "o", color="#d62728", markersize=10)
    cursor = ax_w.axvline(0.0, color="#d62728", linewidth=1.2)
    ax_w.set(xlabel="t (s)", ylabel=r"$\omega_{body,y}$ (rad/s)", title="body-frame rate about y")
    L = problem.R0 @ problem.body.I_body @ problem.R0.T @ np.asarray(problem.initial.angular_velocity, float)
    L_dir = L / np.linalg.norm(L)
    faces = _box_faces((np.sqrt(2.0), 1.0, 0.1))
    colors = ["#d62728", "#d62728", "#1f77b4", "#1f77b4", "#2ca02c", "#2ca02c"]
    idx = np.linspace(0, len(truth) - 1, max(frames, 1)).round().astype(int)
    writer = PillowWriter(fps=GIF_FPS)
    check_output_file(path)  # the rule for every file freebody writes (results.io)
    with writer.saving(fig, str(path), dpi=GIF_DPI):
        for k in idx:
            ax.cla()
            R = matrix_from_quat(truth.quaternion_wxyz[k])
            poly = Poly3DCollection(faces @ R.T, facecolors=colors, edgecolors="k", linewidths=0.5, alpha=0.9)
            ax.add_collection3d(poly)
            y_axis = R[:, 1]
            ax.quiver(0, 0, 0, *(1.1 * y_axis), color="black", linewidth=2.5)
            ax.text(*(1.2 * y_axis), "y", fontsize=14)
            # longer than the box so that its tip shows when the body's y axis points against it
            ax.quiver(0, 0, 0, *(1.35 * L_dir), color="0.55", linewidth=2.0)
            ax.text(*(1.45 * L_dir), "L", fontsize=14, color="0.4")
            for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
                setter(-0.8, 0.8)
            ax.set_box_aspect((1, 1, 1), zoom=1.35)
            ax.set_axis_off()
            ax.set_title(f"t = {truth.t[k]:5.2f} s", fontsize=16)
            dot.set_data([truth.t[k]], [wb[k, 1]])
            cursor.set_xdata([truth.t[k], truth.t[k]])
            writer.grab_frame()


def log_to_stderr(msg: str) -> None:
    """One progress line on stderr (``freebody demo``'s log unless --quiet)."""
    sys.stderr.write(msg + "\n")
    sys.stderr.flush()
