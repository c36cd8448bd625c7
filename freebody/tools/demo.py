"""Teaching demos: slide-ready figures (PNG and SVG) and a short Markdown page per demo.

- ``integrators``: the signed energy error (explicit Euler gains energy, the symplectic splitting's
  error oscillates and stays bounded) and the orientation error against time for the lecture's
  schemes on a tumbling body, the orthonormality error of R without Gram-Schmidt, and the
  convergence plot with fitted slopes (about 1 for the Euler family, 2 for the splitting, 4 for RK4).
- ``quiz``: the lecture's one-step push quiz worked out in closed form for explicit Euler, checked
  against freebody's ``euler-matrix``, and set beside the engines' semi-implicit Euler maps
  (``semi-implicit-explicit-gyro`` / ``semi-implicit-implicit-gyro``) and RK4.
- ``dzhanibekov``: the flip of the intermediate axis in body- and world-frame angular velocity and the
  energy error for each engine, and a GIF of the tumbling box.

Figures are drawn with matplotlib's object API on the Agg canvas (no pyplot state, no display);
matplotlib is imported inside the functions so ``import freebody.tools.demo`` stays light.
"""
from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import tolerances as tol
from ..adapters.base import REFERENCE_ENGINE
from ..input.casefile import load_case
from ..reference_impl.conventions import Trajectory, angular_velocity_body_from_world
from ..reference_impl.integrators import INTEGRATORS, simulate
from ..reference_impl.problem import Problem
from ..reference_impl.rotations import geodesic_angle, matrix_from_quat
from ..reference_impl.truth import truth_trajectory

DEMOS = ("integrators", "quiz", "dzhanibekov")

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

# Quiz demo: the quiz case at the lecture's step.
QUIZ_CASE = "quiz"
QUIZ_DT = 0.1  # s

# Dzhanibekov demo.
DZHANIBEKOV_CASE = "dzhanibekov"
DZHANIBEKOV_DT = 0.01  # s
DZHANIBEKOV_DURATION = 10.0  # s
REFERENCE_IN_DZHANIBEKOV = ("euler-quat", "symplectic-splitting", "rk4")  # the reference's lines beside the engines'
GIF_FRAMES = 80
GIF_FPS = 10

SLIDE_RC = {"font.size": 16, "axes.titlesize": 18, "axes.labelsize": 16, "legend.fontsize": 12,
            "xtick.labelsize": 14, "ytick.labelsize": 14, "lines.linewidth": 2.2,
            "axes.grid": True, "grid.alpha": 0.3, "svg.hashsalt": "freebody", "figure.dpi": 100}
PNG_DPI = 150


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

def _figure(nrows: int = 1, ncols: int = 1, size=(12, 6.75), **kw):
    """A 16:9 figure on an Agg canvas (no pyplot) and its axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return fig, axes


def _save(fig, out_dir: Path, stem: str) -> Path:
    """Save ``stem``.png and ``stem``.svg (reproducible: no dates in the metadata); returns the stem path."""
    base = Path(out_dir) / stem
    fig.savefig(base.with_suffix(".png"), dpi=PNG_DPI, metadata={"Software": None})
    fig.savefig(base.with_suffix(".svg"), metadata={"Date": None})
    return base


def _rc():
    import matplotlib

    return matplotlib.rc_context(SLIDE_RC)


def _write_page(path: Path, text: str) -> Path:
    path.write_text(text.strip() + "\n")
    return path


def _signed_energy_error(problem: Problem, tr: Trajectory) -> np.ndarray:
    """(E(t) - E(0)) / KE(0), shape (N,): the energy error relative to the initial kinetic energy,
    signed (positive: the scheme has gained energy)."""
    from ..run.metrics import energies

    ke, E = energies(problem, tr)
    return (E - E[0]) / ke[0]


def _rel_energy_error(problem: Problem, tr: Trajectory) -> np.ndarray:
    """|E(t) - E(0)| / KE(0), shape (N,): the size of the energy drift (log axes)."""
    return np.abs(_signed_energy_error(problem, tr))


def _with(problem: Problem, duration: float, dt: float) -> Problem:
    return dataclasses.replace(problem, duration=duration, duration_steps=None, dts=(dt,))


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


def convergence_data(problem: Problem, duration: float, dts=CONVERGENCE_DTS) -> dict:
    """Per lecture scheme: the max orientation error (rad) over [0, duration] at each dt, and the
    least-squares slope of log(error) against log(dt) over the errors in tol.DEMO_SLOPE_FIT_RANGE_RAD."""
    out = {}
    for name in LECTURE_SCHEMES:
        errs = []
        for dt in dts:
            steps = int(round(duration / dt))
            tr = simulate(problem, name, dt, steps)
            truth = truth_trajectory(problem, dt, steps)
            errs.append(float(np.max(geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz))))
        errs = np.array(errs)
        lo, hi = tol.DEMO_SLOPE_FIT_RANGE_RAD
        use = (errs > lo) & (errs < hi)
        slope = float(np.polyfit(np.log(np.array(dts)[use]), np.log(errs[use]), 1)[0]) if use.sum() >= 2 else None
        out[name] = {"dt": list(dts), "error": errs.tolist(), "slope": slope, "order": INTEGRATORS[name].order}
    return out


def demo_integrators(out_dir: Path, dt: float = INTEGRATORS_DT, duration: float = INTEGRATORS_DURATION,
                     convergence_duration: float = CONVERGENCE_DURATION,
                     convergence_dts=CONVERGENCE_DTS) -> DemoOutput:
    """Four figures and ``integrators.md``."""
    base = load_case(INTEGRATORS_CASE)
    problem = _with(base, duration, dt)
    data = integrators_data(problem, dt, duration)
    conv = convergence_data(_with(base, convergence_duration, dt), convergence_duration, convergence_dts)
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
                 "orthonormality_final": ortho}
    rows = "\n".join(f"| `{n}` | {INTEGRATORS[n].summary} | {final[n]['energy']:+.2e} | "
                     f"{final[n]['orientation']:.2e} | {_fmt_slope(conv[n]['slope'])} |"
                     for n in LECTURE_SCHEMES)
    zoom = final["symplectic-splitting"]
    _write_page(res.page, _integrators_page(dt, duration, steps, convergence_duration, rows, ortho,
                                            zoom["energy_min_signed"], zoom["energy_max_signed"]))
    return res


def _plot_integrator_errors(data: dict, dt: float, out_dir: Path) -> list[Path]:
    """The signed energy-error figure (linear, all schemes above, the bounded ones zoomed below, the
    exact energy's zero line on top) and the orientation-error figure (log scale) of integrators_data."""
    fig, axes = _figure(2, 1, sharex=True)
    ax_all, ax_zoom = axes[:, 0]
    for ax, names in ((ax_all, LECTURE_SCHEMES), (ax_zoom, ENERGY_ZOOM_SCHEMES)):
        for name in names:
            ax.plot(data[name]["t"], data[name]["energy"], color=SCHEME_COLORS[name], label=name,
                    linestyle=SCHEME_STYLES.get(name, "-"))
        ax.axhline(0.0, color="black", linewidth=1.5, label="truth (E conserved)")
    ax_all.set(ylabel="(E(t) - E(0)) / KE(0)",
               title=f"Energy error, signed: explicit Euler gains energy (tumbling body, dt = {dt:g} s)")
    ax_zoom.set(xlabel="t (s)", ylabel="(E(t) - E(0)) / KE(0)",
                title="Zoom: the splitting's error oscillates, bounded; the implicit midpoint's stays at 0")
    ax_all.legend(loc="upper left", ncols=2, fontsize=11)
    ax_zoom.legend(loc="upper left", ncols=3, fontsize=11)
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
    fig, ax = _figure()  # 16:9, like every slide of the demo
    ax = ax[0, 0]
    for name in LECTURE_SCHEMES:
        c = conv[name]
        slope = "-" if c["slope"] is None else f"{c['slope']:.2f}"
        ax.loglog(c["dt"], c["error"], marker="o", color=SCHEME_COLORS[name],
                  linestyle=SCHEME_STYLES.get(name, "-"), label=f"{name}: slope {slope}")
    ax.set(xlabel="dt (s)", ylabel="max orientation error (rad)",
           title=f"Convergence over {convergence_duration:g} s")
    ax.legend(loc="lower right")
    return _save(fig, out_dir, "integrators_convergence")


def _integrators_page(dt: float, duration: float, steps: int, convergence_duration: float, rows: str,
                      ortho: float, split_min: float, split_max: float) -> str:
    """The Markdown of ``integrators.md``: ``rows`` is the table body, ``ortho`` the final
    orthonormality error of euler-matrix, ``split_min``/``split_max`` the range of the symplectic
    splitting's signed energy error."""
    return f"""
# Integrators on a tumbling body

The body of the bundled case `{INTEGRATORS_CASE}`: I = diag(1, 2, 3) kg m^2, no gravity, tumbling about
its major axis; the truth is the closed-form torque-free motion. Every scheme runs {steps} steps of
dt = {dt:g} s ({duration:g} s). Reproduce the numbers with
`freebody run {INTEGRATORS_CASE} --engine reference --dt {dt:g} --duration {duration:g}`.

| scheme | what it does | energy error (E - E0) / KE0 at {duration:g} s | orientation error at {duration:g} s (rad) | observed order |
| --- | --- | --- | --- | --- |
{rows}

## Energy error, signed

![energy](integrators_energy.png)

The energy error with its sign, (E(t) - E(0)) / KE(0); the exact motion keeps it at 0 (the black
line). Explicit Euler *gains* energy, step after step: on the matrix (`euler-matrix`) most, because
each step moves R along the tangent, off the rotations, and the body's apparent inertia changes with
it; Gram-Schmidt (`euler-matrix-gs`) removes that part, and what is left still drifts. `euler-quat` and
`lie-euler` nearly coincide (drawn dashed over each other): without torque L never changes,
so updating the momenta first changes nothing, and what is left is an explicit Euler step on the
rotations (the Lie-Euler method), w taken at the old orientation. Momenta first is symplectic Euler
for the translation only: it bounds the energy of a separable H = T(p) + V(x), but the rotational
energy 1/2 L . R I_b^-1 R^T L depends on the orientation R as well as on L, and a symplectic Euler
step would need w at the *new* R (an implicit step). (Before freebody 0.2.0 `lie-euler` was called
`symplectic-euler`, a name that still works.)

`symplectic-splitting` is symplectic: it splits the rotational energy into parts whose motions are
exact rotations (a sphere's about L, corrections about two principal axes) and composes them
symmetrically (Dullweber, Leimkuhler & McLachlan 1997). It solves a slightly different rigid body
exactly, so its energy error oscillates and stays bounded, between {split_min:+.1e} and
{split_max:+.1e} here (lower panel), for as long as you run it; it does not drift. RK4 is more
accurate at this step (its error is much smaller) but is not symplectic: over very long runs its
error grows slowly, while the splitting's stays where it is.

## Orientation error

![orientation](integrators_orientation.png)

All the first-order schemes drift away from the true orientation at a rate proportional to dt;
RK4's error is proportional to dt^4.

## R without Gram-Schmidt

![orthonormality](integrators_orthonormality.png)

Explicit Euler on the matrix, R <- R + h [w] R, multiplies the length of every column by about
sqrt(1 + h^2 |w|^2) per step: R stops being a rotation (here ||R^T R - 1||_F = {ortho:.2g} after
{duration:g} s) and the body appears to grow. Re-orthonormalising after each step (Gram-Schmidt) keeps
it at round-off, but does not make the scheme more accurate.

## Convergence

![convergence](integrators_convergence.png)

The maximum orientation error over {convergence_duration:g} s against dt, on a log-log scale. The slope is
the observed order: about 1 for the Euler family (halve dt, halve the error), about 2 for the
symplectic splitting (error / 4) and about 4 for RK4 (halve dt, error / 16). The horizon is short so that explicit Euler has not saturated (errors above
about 1 rad no longer shrink with dt, and the fitted slope would be meaningless).
"""


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


def quiz_rows(problem: Problem, h: float, engines: list[str] | None, log=None) -> list[QuizRow]:
    """The quiz at t2 for the closed form, the reference schemes, every installed engine's
    integrators (missing or failing engines as rows with their status), and the truth."""
    from ..run import RunSpec, execute, engine_integrators, select_engines

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
        for integ in offered:
            if log:
                log(f"quiz: {engine}/{integ}")
            out = execute(RunSpec(problem, engine, integ, h, 2), identify_scheme=False)
            tr = out.trajectory
            family = "rk4" if "rk4" in integ.lower() else "semi-implicit"
            if tr is None or len(tr) < 3:
                rows.append(QuizRow(f"{engine} {integ}", family, None, None, None, None,
                                    f"{out.result.status}: {out.result.message}"))
                continue
            rows.append(QuizRow(f"{engine} {integ}", family, tr.position[2], _angle_z(tr.quaternion_wxyz[2]),
                                tr.linear_velocity[2], tr.angular_velocity[2]))
    truth = truth_trajectory(problem, h, 2)
    rows.append(QuizRow("truth (DOP853)", "truth", truth.position[2], _angle_z(truth.quaternion_wxyz[2]),
                        truth.linear_velocity[2], truth.angular_velocity[2]))
    return rows


FAMILY_COLORS = {"explicit": "#d62728", "semi-implicit": "#1f77b4", "rk4": "#2ca02c", "truth": "#000000"}


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
    _write_page(res.page, _quiz_page(cf, h, table))
    return res


def _vec(a) -> str:
    """A vector as "(x, y, z)" with 4 significant digits."""
    return "(" + ", ".join(f"{x:.4g}" for x in a) + ")"


def _plot_quiz(drawn: list[QuizRow], truth: QuizRow, h: float, out_dir: Path) -> Path:
    """Bars of x2 and of the rotation angle at t2 per drawn row, coloured by family, the truth
    dashed."""
    fig, axes = _figure(1, 2, size=(14, 7.5), sharey=True)
    labels = [r.label for r in drawn][::-1]
    ypos = np.arange(len(labels))
    for ax, values, exact, xlabel in (
            (axes[0, 0], [r.x2[0] * 100 for r in drawn][::-1], truth.x2[0] * 100, "x2, x component (cm)"),
            (axes[0, 1], [np.degrees(r.angle2) for r in drawn][::-1], np.degrees(truth.angle2),
             "rotation about z at t2 (deg)")):
        colors = [FAMILY_COLORS[r.family] for r in drawn][::-1]
        ax.barh(ypos, values, color=colors)
        ax.axvline(exact, color="black", linestyle="--", linewidth=1.5)
        ax.set_xlabel(xlabel)
        ax.grid(axis="y", visible=False)
    axes[0, 0].set_yticks(ypos, labels)
    from matplotlib.patches import Patch

    present = dict.fromkeys(r.family for r in drawn)
    names = {"explicit": "explicit Euler", "semi-implicit": "semi-implicit Euler (engines' map)", "rk4": "RK4",
             "truth": "truth"}
    fig.legend(handles=[Patch(color=FAMILY_COLORS[f], label=names[f]) for f in present],
               loc="outside lower center", ncols=len(present))
    fig.suptitle(f"The push quiz after two steps of h = {h:g} s (dashed: the exact motion)")
    return _save(fig, out_dir, "quiz_t2")


def _quiz_page(cf: dict, h: float, table: str) -> str:
    """The Markdown of ``quiz.md``: ``cf`` from quiz_closed_form, ``table`` the table body."""
    F, tau, g, m = cf["F"], cf["tau"], cf["g"], cf["m"]
    return f"""
# The push quiz, worked out

A sphere of m = {m:g} kg, radius 1 m (I = 2/5 m r^2 = 0.4 kg m^2), at rest at the origin under gravity
g = {_vec(g)} m/s^2, is pushed for one step of h = {h:g} s by F = 4 N at 30 deg, F = {_vec(F)} N, at the world
point r = (-1, 0, 0) m. The torque about the COM is tau = r x F = {_vec(tau)} N m. Where is it after two
steps (t2 = 2h)? Bundled as the case `quiz` (`freebody run quiz`).

## Explicit Euler in closed form

Explicit Euler on (x, R, P, L) updates every variable with the derivative at the *start* of the step:

- step 1 (t0 -> t1, push on): x1 = x0 + h P0/m = 0, R1 = R0 + h [w0] R0 = 1, P1 = h (F + m g), L1 = h tau;
- step 2 (t1 -> t2, push off): x2 = x1 + h P1/m, R2 = R1 + h [w1] R1 with w1 = I^-1 L1.

So **x2 = h^2 (F/m + g)** = {_vec(cf['x2'])} m, **R2 = 1 + h [w1]** with **w1 = (0, 0, -5h)** =
{_vec(cf['w1'])} rad/s, **P2 = hF + 2hmg** = {_vec(cf['P2'])} kg m/s, **L2 = (0, 0, -2h)** = {_vec(cf['L2'])} kg m^2/s.
R2 is not a rotation: det R2 = 1 + 25 h^4 = {np.linalg.det(cf['R2']):.6g}.

## Every scheme at t2

![quiz](quiz_t2.png)

| scheme | x2 (m) | angle about z (deg) | v2 (m/s) | w2 (rad/s) |
| --- | --- | --- | --- | --- |
{table}

## Why they differ

- **Explicit Euler** (freebody's `euler-matrix`, equal to the closed form to round-off) moves with the
  *old* velocity: the push changes P and L during step 1 but x and R only from step 2 on. It lags:
  x2 is h^2 F/m along x, and the body has turned by atan(5 h^2) only.
- **Semi-implicit Euler** (freebody's `semi-implicit-explicit-gyro` and
  `semi-implicit-implicit-gyro`), the map of MuJoCo `Euler`/`implicit*`, PyBullet and DART,
  updates the velocities first and moves with the *new* ones: the push already moves and turns the body
  in step 1. It leads: x2 = h^2 (2F/m + 3g), angle -10 h^2.
- **RK4** (freebody's `rk4`, MuJoCo `RK4`) integrates a force held constant over a step exactly:
  x2 = h^2 (3F/(2m) + 2g), angle -7.5 h^2, the same as the truth.
- The small x and y components of the exact w2: the push acts at a point fixed in the *world*, and
  gravity moves the COM during step 1, so the arm r - x(t) and the torque tilt a little. freebody's
  `rk4` evaluates the arm at each stage and follows the truth; MuJoCo's `RK4` holds the wrench of
  the step's start.

The exact answer lies between the two first-order schemes; the gap shrinks like h (try
`freebody run quiz --dt 0.01`), and the three engines' agreement with each other says which scheme they
implement, not that they are exact.
"""


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
        for integ in chosen:
            if log:
                log(f"dzhanibekov: {engine}/{integ}")
            r = execute(RunSpec(problem, engine, integ, dt, steps), cache, identify_scheme=False)
            ok = r.trajectory is not None and r.result.status == Status.OK
            out.append((f"{engine}/{integ}" if integ != "*" else engine, r.trajectory if ok else None,
                        Status.OK.value if ok else f"{r.result.status}: {r.result.message}"))
    return out


def demo_dzhanibekov(out_dir: Path, engines: list[str] | None = None, dt: float = DZHANIBEKOV_DT,
                     duration: float = DZHANIBEKOV_DURATION, frames: int = GIF_FRAMES, log=None) -> DemoOutput:
    """Angular velocity (body and world) and energy error per engine, a GIF, ``dzhanibekov.md``."""
    problem = _with(load_case(DZHANIBEKOV_CASE), duration, dt)
    steps = int(round(duration / dt))
    truth = truth_trajectory(problem, dt, steps)
    runs = dzhanibekov_runs(problem, dt, steps, engines, log=log)
    res = DemoOutput("dzhanibekov", out_dir / "dzhanibekov.md")
    wb_true = angular_velocity_body_from_world(truth.quaternion_wxyz, truth.angular_velocity)
    with _rc():
        res.figures.append(_plot_dzhanibekov(problem, truth, wb_true, runs, out_dir))
        gif = out_dir / "dzhanibekov.gif"
        _animate_box(truth, gif, frames)
        res.files.append(gif)

    flips = _flip_times(truth.t, wb_true[:, 1])
    res.facts = {"flip_times_s": flips, "runs": [{"label": lab, "status": st} for lab, _, st in runs]}
    missing = "\n".join(f"- {lab}: {st}" for lab, tr, st in runs if tr is None) or "- none"
    finals = "\n".join(
        f"| {lab} | {np.nanmax(_rel_energy_error(problem, tr)):.2e} | "
        f"{np.max(geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz)):.3g} |"
        for lab, tr, _ in runs if tr is not None)
    _write_page(res.page, _dzhanibekov_page(dt, duration, flips, finals, missing))
    return res


def _plot_dzhanibekov(problem: Problem, truth: Trajectory, wb_true: np.ndarray, runs: list,
                      out_dir: Path) -> Path:
    """Three panels against t: body-frame w_y, world-frame w_x and the energy error, for the truth
    (``wb_true``: its body-frame angular velocity (N, 3)) and every run of dzhanibekov_runs that
    has a trajectory."""
    styles = ["-", "--", "-.", ":"]
    fig, axes = _figure(3, 1, size=(12, 11), sharex=True)
    ax_b, ax_w, ax_e = axes[:, 0]
    ax_b.plot(truth.t, wb_true[:, 1], color="black", linewidth=4, alpha=0.35, label="truth")
    ax_w.plot(truth.t, truth.angular_velocity[:, 0], color="black", linewidth=4, alpha=0.35)
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    drawn = [(lab, tr) for lab, tr, _ in runs if tr is not None]
    for k, (label, tr) in enumerate(drawn):
        color, ls = cmap(k % 10), styles[k % len(styles)]
        wb = angular_velocity_body_from_world(tr.quaternion_wxyz, tr.angular_velocity)
        ax_b.plot(tr.t, wb[:, 1], color=color, linestyle=ls, label=label)
        ax_w.plot(tr.t, tr.angular_velocity[:, 0], color=color, linestyle=ls)
        ax_e.semilogy(tr.t, np.maximum(_rel_energy_error(problem, tr), 1e-17), color=color, linestyle=ls)
    ax_b.set(ylabel=r"$\omega_{body,y}$ (rad/s)", title="The intermediate axis flips (Dzhanibekov effect)")
    ax_w.set(ylabel=r"$\omega_{world,x}$ (rad/s)")
    ax_e.set(xlabel="t (s)", ylabel="|E - E0| / E0")
    ax_b.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=11)
    return _save(fig, out_dir, "dzhanibekov_flip")


def _dzhanibekov_page(dt: float, duration: float, flips: list[float], finals: str, missing: str) -> str:
    """The Markdown of ``dzhanibekov.md``: ``finals`` the table body, ``missing`` the list of runs
    not drawn."""
    return f"""
# The Dzhanibekov effect in every engine

The bundled case `dzhanibekov`: I = diag(1, 2, 3) kg m^2, spinning at 5 rad/s about the intermediate
axis (body y) with a 0.01 rad/s nudge about x; no gravity, no torque. Rotation about the intermediate
axis is unstable: the body flips over every few seconds (here at t = {', '.join(f'{t:.2f}' for t in flips)} s)
while L stays fixed in the world. dt = {dt:g} s, {duration:g} s.

![flip](dzhanibekov_flip.png)

- **Top**: the angular velocity about the body's y axis: it reverses at each flip.
- **Middle**: the world-frame x component, zero at the start: it bursts during each flip, because
  w = I(t)^-1 L changes as the body turns even though L does not.
- **Bottom**: the energy error. The engines' first-order semi-implicit maps gain or lose about 10%,
  most of it on the way into the first flip, where every error is amplified; explicit Euler
  (`reference/euler-quat`) gains more and soon flips at the wrong times; the symplectic splitting
  (`reference/symplectic-splitting`, second order) keeps it bounded, oscillating below about 3e-5
  with no drift; RK4 (freebody's and MuJoCo's) stays below 1e-7.

Engines that implement the same map draw on top of one another (dashed and dotted lines over solid);
the small phase error of the first-order schemes makes them flip a little early or late.

| engine/integrator | energy error max | orientation error max (rad) |
| --- | --- | --- |
{finals}

Not drawn:
{missing}

## The tumbling box

![tumbling box](dzhanibekov.gif)

The exact motion; the box has the case's inertia (edges in proportion sqrt(2) : 1 : 0.1); the arrow
is the body's intermediate (y) axis.
"""


def _flip_times(t: np.ndarray, wy: np.ndarray) -> list[float]:
    """Times (s) at which the body-frame intermediate-axis rate changes sign."""
    s = np.sign(wy)
    idx = np.flatnonzero(s[1:] * s[:-1] < 0)
    return [float(t[i]) for i in idx]


def _box_faces(size) -> np.ndarray:
    """The 6 faces of a centred box, shape (6, 4, 3), m, body frame."""
    a, b, c = np.asarray(size) / 2
    v = np.array([[x, y, z] for x in (-a, a) for y in (-b, b) for z in (-c, c)])
    idx = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return np.array([[v[i] for i in f] for f in idx])


def _animate_box(truth: Trajectory, path: Path, frames: int) -> None:
    """A GIF of the box tumbling along ``truth`` (``frames`` frames at GIF_FPS), via PillowWriter."""
    from matplotlib.animation import PillowWriter
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig, _ = _figure(size=(4.5, 4.5))
    fig.clear()
    ax = fig.add_subplot(projection="3d")
    faces = _box_faces((np.sqrt(2.0), 1.0, 0.1))
    colors = ["#d62728", "#d62728", "#1f77b4", "#1f77b4", "#2ca02c", "#2ca02c"]
    idx = np.linspace(0, len(truth) - 1, max(frames, 1)).round().astype(int)
    writer = PillowWriter(fps=GIF_FPS)
    with writer.saving(fig, str(path), dpi=72):
        for k in idx:
            ax.cla()
            R = matrix_from_quat(truth.quaternion_wxyz[k])
            poly = Poly3DCollection(faces @ R.T, facecolors=colors, edgecolors="k", linewidths=0.5, alpha=0.9)
            ax.add_collection3d(poly)
            y_axis = R[:, 1]
            ax.quiver(0, 0, 0, *(1.1 * y_axis), color="black", linewidth=2.5)
            ax.text(*(1.2 * y_axis), "y", fontsize=12)
            for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
                setter(-0.9, 0.9)
            ax.set_box_aspect((1, 1, 1))
            ax.set_axis_off()
            ax.set_title(f"t = {truth.t[k]:5.2f} s", fontsize=12)
            writer.grab_frame()


def _stderr(msg: str) -> None:
    sys.stderr.write(msg + "\n")
    sys.stderr.flush()
