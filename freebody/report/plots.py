"""The report's figures, drawn with matplotlib's object API on the Agg canvas, returned as PNG bytes.

No pyplot (no global state, no GUI backend).  Only finite values are drawn: a NaN, an inf or (on a
log axis) a non-positive value is left out, never plotted as a number.  Each figure is small and
few per case (one 4-panel figure per case and dt), so a 150-run report renders in seconds.
"""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from . import data as rd
from .. import tolerances as tol
from ..numbers import finite_or_none
from ..run.convergence import FITTED_METRICS, MIN_POINTS
from ..run.metrics import ORIENTATION_ERROR_MAX
from ..run.records import Status

DPI = 90
MAX_POINTS = 800  # samples drawn per line: more is invisible at this size, and slow
LOG_PANEL_TOP = 1e3  # error panels stop here: beyond, a run has blown up (its status says so)
STATUS_COLOURS = {Status.DIVERGED: "#222222", Status.FAILED: "#b2182b", Status.SKIPPED: "#d9d9d9"}
STATUS_TEXT = {Status.DIVERGED: "div", Status.FAILED: "fail", Status.SKIPPED: "skip"}
TRUTH_STYLE = dict(color="black", linestyle="--", linewidth=1.2)


def _figure(width_in: float, height_in: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=DPI)


def png_bytes(fig) -> bytes:
    """The figure as PNG (no software metadata, so the bytes depend on the data only)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def colours(labels: list[str]) -> dict[str, tuple]:
    """A fixed colour per engine-run label (tab10 up to 10 labels, tab20 up to 20, then cycling)."""
    from matplotlib import colormaps

    cmap = colormaps["tab10" if len(labels) <= 10 else "tab20"]
    n = cmap.N
    return {lab: cmap(i % n) for i, lab in enumerate(labels)}


def linestyle(i: int, n_colours: int) -> str:
    return ("-", "--", ":", "-.")[(i // n_colours) % 4]


def _finite_xy(x, y, log_y: bool = False, log_x: bool = False):
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(x) & np.isfinite(y)
    if log_y:
        ok &= y > 0
    if log_x:
        ok &= x > 0
    return x[ok], y[ok]


def _decimate(n: int) -> slice:
    return slice(None, None, max(1, int(np.ceil(n / MAX_POINTS))))


def _legend_in(n: int, ncol: int = 4) -> float:
    """Height in inches of a figure legend of n entries in ncol columns at fontsize 7."""
    return 0.17 * ((n + ncol - 1) // ncol) + 0.1


def _log_axes(ax, x: bool = False, y: bool = False) -> None:
    """Log scale with labels on the decades only (minor tick labels are slow and crowded)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

    for on, axis, setter in ((x, ax.xaxis, ax.set_xscale), (y, ax.yaxis, ax.set_yscale)):
        if on:
            setter("log")
            axis.set_major_locator(LogLocator(base=10, numticks=8))
            axis.set_major_formatter(FuncFormatter(_decade))  # plain text: mathtext is slow
            axis.set_minor_locator(NullLocator())  # hundreds of minor ticks over 16 decades: slow


def _decade(v: float, _pos=None) -> str:
    """A log-axis tick label: 1e-4 for a decade, %g otherwise."""
    if not (v > 0 and np.isfinite(v)):
        return ""
    e = np.log10(v)
    return f"1e{int(round(e))}" if abs(e - round(e)) < tol.PLOT_DECADE_TICK_ATOL else f"{v:g}"


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=8, color="0.4")


# --- front page -----------------------------------------------------------------------------------

def heatmap(runs: list[dict]) -> bytes | None:
    """Cases (rows) x engine runs (columns), coloured by the worst orientation error (log scale);
    diverged, failed and skipped cells in their own colours with a word."""
    from matplotlib.colors import LogNorm

    cases = list(rd.by_case(runs))
    labs = rd.labels(runs)
    if not cases or not labs:
        return None
    cells = rd.worst_cells(runs)
    data = np.full((len(cases), len(labs)), np.nan)
    for (c, lab), (status, v) in cells.items():
        if status == Status.OK and v is not None:
            data[cases.index(c), labs.index(lab)] = max(v, 1e-16)
    label_in = 0.045 * max(map(len, labs)) * 0.87 + 0.3  # rotated tick labels, inches
    case_in = 0.07 * max(map(len, cases)) + 0.3
    w, h = max(5.0, case_in + 1.6 + 0.62 * len(labs)), 0.8 + 0.42 * len(cases) + label_in
    fig = _figure(w, h)
    ax = fig.add_axes((case_in / w, label_in / h, 1 - (case_in + 1.5) / w, 1 - (label_in + 0.45) / h))
    finite = data[np.isfinite(data)]
    cmap = None
    if finite.size:
        from matplotlib import colormaps

        cmap = colormaps["viridis"].with_extremes(bad="white")
        lo, hi = float(finite.min()), float(finite.max())
        norm = LogNorm(vmin=lo, vmax=hi if hi > lo else lo * 10)
        im = ax.imshow(np.ma.masked_invalid(data), cmap=cmap, norm=norm, aspect="auto")
        cax = fig.add_axes((1 - 1.3 / w, label_in / h, 0.15 / w, 1 - (label_in + 0.45) / h))
        from matplotlib.ticker import FuncFormatter, NullFormatter

        fig.colorbar(im, cax=cax).set_label("orientation error max (rad)", fontsize=8)
        cax.yaxis.set_major_formatter(FuncFormatter(_decade))
        cax.yaxis.set_minor_formatter(NullFormatter())
        cax.tick_params(labelsize=7)
    else:
        ax.imshow(np.zeros_like(data), cmap="Greys", vmin=0, vmax=1, aspect="auto")
    for (c, lab), (status, v) in cells.items():
        i, j = cases.index(c), labs.index(lab)
        if status != Status.OK:
            ax.add_patch(_cell_patch(j, i, STATUS_COLOURS.get(status, "#ff00ff")))
            ax.text(j, i, STATUS_TEXT.get(status, status), ha="center", va="center", fontsize=7,
                    color="white" if status in (Status.DIVERGED, Status.FAILED) else "black")
        elif v is not None:
            rgba = cmap(norm(max(v, 1e-16))) if cmap is not None else (1, 1, 1, 1)
            light = 0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2] > 0.5
            ax.text(j, i, format(v, ".0e"), ha="center", va="center", fontsize=6.5,
                    color="black" if light else "white")
    ax.set_xticks(range(len(labs)), labs, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(cases)), cases, fontsize=8)
    ax.set_title("worst orientation error over time and time steps (rad); "
                 "div = diverged, fail = failed, skip = skipped", fontsize=9, loc="left")
    return png_bytes(fig)


def _cell_patch(x: float, y: float, colour: str):
    from matplotlib.patches import Rectangle

    return Rectangle((x - 0.5, y - 0.5), 1, 1, facecolor=colour, edgecolor="white", linewidth=0.5)


def convergence(runs: list[dict], entries: list[dict]) -> bytes | None:
    """Error vs dt (log-log), one line per engine run.  For the cases run at >= 3 time steps (where
    orders are fitted): a row per case with the orientation and the energy error and the fitted
    order in the legend ('sat.' where the errors saturate).  Without such a case: the orientation
    error of the cases run at 2 time steps, one panel per case (no order)."""
    n_dts = {c: len(rd.dts(rs)) for c, rs in rd.by_case(runs).items()}
    fitted = [c for c, n in n_dts.items() if n >= MIN_POINTS]
    if fitted:
        return _convergence_rows(runs, entries, fitted)
    two = [c for c, n in n_dts.items() if n >= 2]
    if not two:
        return None
    return _per_case_grid(runs, two, lambda r: r["dt"], "dt (s)",
                          f"no order fitted: no case ran at {MIN_POINTS} or more time steps", dt_ticks=True)


def _dt_axis(ax, dts: list[float]) -> None:
    from matplotlib.ticker import NullLocator

    ax.set_xticks(dts, [f"{d:g}" for d in dts])  # the dts themselves: often less than a decade apart
    ax.xaxis.set_minor_locator(NullLocator())


def _convergence_rows(runs: list[dict], entries: list[dict], cases: list[str]) -> bytes:
    labs = rd.labels(runs)
    col = colours(labs)
    fits = {(e["case"], rd.label(e), e["metric"]): e for e in entries}
    by_case = rd.by_case(runs)
    row_in = max(3.0, 0.115 * max(len(rd.labels(by_case[c])) for c in cases) + 0.7)  # room for the legend
    fig = _figure(11.0, row_in * len(cases) + 0.4)
    fig.subplots_adjust(left=0.07, right=0.99, bottom=0.6 / fig.get_figheight(), top=1 - 0.35 / fig.get_figheight(),
                        wspace=0.3, hspace=0.45)
    for row, case in enumerate(cases):
        case_runs = by_case[case]
        handles = []
        axes = [fig.add_subplot(len(cases), 3, 3 * row + k + 1) for k in range(2)]
        for lab in rd.labels(case_runs):
            mine = sorted((r for r in case_runs if rd.label(r) == lab), key=lambda r: float(r["dt"]))
            ls = linestyle(labs.index(lab), 10 if len(labs) <= 10 else 20)
            orders = []
            for ax, m in zip(axes, FITTED_METRICS):
                x, y = _finite_xy([r["dt"] for r in mine],
                                  [rd.metric(r, m) if r.get("status") == Status.OK else None for r in mine],
                                  log_y=True, log_x=True)
                h = ax.plot(x, y, marker="o", markersize=3, color=col[lab], linestyle=ls, linewidth=1)[0]
                e = fits.get((case, lab, m))
                if e and e.get("order") is not None and e.get("log10_coefficient") is not None:
                    fd = np.asarray(e["fitted_dts"], dtype=float)
                    ax.plot(fd, 10 ** e["log10_coefficient"] * fd ** e["order"], color=col[lab],
                            linewidth=0.6, alpha=0.6, linestyle=":")
                orders.append("-" if not e else ("sat." if e.get("saturated") else rd.num(e.get("order"), ".2f")))
                if m == FITTED_METRICS[0]:
                    first = h
            handles.append((first, f"{lab}  p = {orders[0]} / {orders[1]}"))
        for ax, m in zip(axes, FITTED_METRICS):
            _log_axes(ax, x=True, y=True)
            _dt_axis(ax, rd.dts(case_runs))
            ax.set_xlabel("dt (s)", fontsize=8)
            ax.set_ylabel("orientation error max (rad)" if m == FITTED_METRICS[0] else "energy error max (rel)",
                          fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(True, which="major", alpha=0.3)
            ax.set_title(case, fontsize=9)
            if not any(len(ln.get_xdata()) for ln in ax.lines):
                _empty(ax, "no ok run")
        lax = fig.add_subplot(len(cases), 3, 3 * row + 3)
        lax.axis("off")
        lax.legend([h for h, _ in handles], [t for _, t in handles], loc="center left", fontsize=6.5,
                   title="order p (orientation / energy)", title_fontsize=7, frameon=False)
    return png_bytes(fig)


def _per_case_grid(runs: list[dict], cases: list[str], x_of, xlabel: str, title: str | None = None,
                   dt_ticks: bool = False) -> bytes:
    """A grid of panels (3 per row), one per case: orientation error max (log) against x_of(run)
    (log), one line per engine run through its time steps, one legend for all panels."""
    labs = rd.labels(runs)
    col = colours(labs)
    ncol = min(3, len(cases))
    nrow = (len(cases) + ncol - 1) // ncol
    head = 0.35 + (0.35 if title else 0.0)
    fig = _figure(4.0 * ncol, 3.1 * nrow + _legend_in(len(labs)) + 0.2 + head)
    handles = {}
    by_case = rd.by_case(runs)
    for k, case in enumerate(cases):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        case_runs = by_case[case]
        for lab in rd.labels(case_runs):
            mine = sorted((r for r in case_runs if rd.label(r) == lab), key=lambda r: float(r["dt"]))
            x, y = _finite_xy([x_of(r) for r in mine],
                              [rd.metric(r, ORIENTATION_ERROR_MAX) if r.get("status") == Status.OK else None
                               for r in mine], log_x=True, log_y=True)
            if len(x):
                handles[lab] = ax.plot(x, y, marker="o", markersize=3, linewidth=1, color=col[lab],
                                       linestyle=linestyle(labs.index(lab), 10 if len(labs) <= 10 else 20))[0]
        _log_axes(ax, x=True, y=True)
        if dt_ticks:
            _dt_axis(ax, rd.dts(case_runs))
        ax.set_title(case, fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel("orientation error max (rad)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, which="major", alpha=0.3)
        if not any(len(ln.get_xdata()) for ln in ax.lines):
            _empty(ax, "no ok run to draw")
    if title:
        fig.suptitle(title, fontsize=9, y=1 - 0.12 / fig.get_figheight())
    if handles:
        fig.legend([handles[lab] for lab in labs if lab in handles], [lab for lab in labs if lab in handles],
                   loc="lower center", ncol=4, fontsize=7, frameon=False)
    h = fig.get_figheight()
    fig.subplots_adjust(left=0.08, right=0.98, top=1 - head / h, bottom=(_legend_in(len(handles)) + 0.5) / h,
                        wspace=0.3, hspace=0.5)
    return png_bytes(fig)


def speed_accuracy(runs: list[dict]) -> bytes | None:
    """Per case: orientation error max vs wall time per simulated second (log-log), one line per
    engine run through its time steps."""
    cases = list(rd.by_case(runs))
    if not cases:
        return None
    return _per_case_grid(runs, cases, rd.wall_per_simulated_s, "wall time per simulated second (s/s)")


# --- per case and dt ------------------------------------------------------------------------------

def case_dt(case: str, dt: float, runs: list[dict], physics: rd.CasePhysics | None, out_dir: Path,
            all_labels: list[str]) -> tuple[bytes | None, list[str]]:
    """One 4-panel figure for the runs of a case at one dt: orientation error (log), energy error
    (log), angular momentum error (log), world angular velocity components vs the truth.
    Returns (PNG bytes or None, notes about runs that could not be drawn)."""
    loaded, truth_shown, notes = _load_case_runs(runs, physics, out_dir)
    if not loaded:
        return None, notes
    fig = _figure(11.0, 7.0 + _legend_in(len(loaded)))
    axes = [fig.add_subplot(2, 2, k + 1) for k in range(4)]
    handles = _draw_case_runs(axes, loaded, colours(all_labels), all_labels)
    if truth_shown is not None:
        _draw_truth_angular_velocity(axes[3], truth_shown)
    _style_case_panels(axes, physics)
    fig.suptitle(f"{case}, dt = {dt:g} s", fontsize=10)
    if handles:
        labs = [lab for lab in all_labels if lab in handles]
        fig.legend([handles[lab] for lab in labs], labs, loc="lower center", ncol=4, fontsize=7, frameon=False)
    h = fig.get_figheight()
    fig.subplots_adjust(left=0.07, right=0.98, top=1 - 0.55 / h, bottom=(_legend_in(len(handles)) + 0.5) / h,
                        wspace=0.2, hspace=0.4)
    return png_bytes(fig), notes


def _load_case_runs(runs: list[dict], physics: rd.CasePhysics | None, out_dir: Path):
    """The drawable runs of case_dt with their error series, read from their trajectory files.

    Returns (loaded, truth_shown, notes): loaded holds (run, t, keep, orientation error, metric
    series or None, world angular velocity) per ok or diverged run with a readable trajectory and
    truth, keep masking the samples after a divergence; truth_shown is the longest truth (a
    diverged run's is cut short), or None; notes say why a run could not be drawn."""
    from ..run.metrics import series
    from ..reference_impl.rotations import geodesic_angle
    from ..results.document import load_trajectory

    notes = []
    loaded = []
    truth_shown = None
    for r in runs:
        if r.get("status") not in (Status.OK, Status.DIVERGED) or not r.get("trajectory"):
            continue
        try:
            tr, truth = load_trajectory(Path(out_dir) / r["trajectory"])
        except (OSError, KeyError, ValueError) as e:
            notes.append(f"{rd.label(r)}: trajectory file {r['trajectory']} unreadable ({type(e).__name__})")
            continue
        if truth is None or len(tr) == 0:
            notes.append(f"{rd.label(r)}: no truth in {r['trajectory']}")
            continue
        n = min(len(tr), len(truth))
        t_end = finite_or_none(r.get("diverged_at_s"))
        keep = np.ones(n, bool) if t_end is None else (tr.t[:n] <= t_end)
        with np.errstate(all="ignore"):
            ori = geodesic_angle(truth.quaternion_wxyz[:n], tr.quaternion_wxyz[:n])
            s = series(physics, tr, truth) if physics is not None else None
        loaded.append((r, tr.t[:n], keep, ori, s, tr.angular_velocity[:n]))
        if truth_shown is None or len(truth) > len(truth_shown):  # a diverged run's truth is cut short
            truth_shown = truth
    return loaded, truth_shown, notes


def _draw_case_runs(axes: list, loaded: list, col: dict, all_labels: list[str]) -> dict:
    """Each loaded run's three error curves and its angular velocity components on case_dt's
    axes; returns {label: line handle} for the legend."""
    handles = {}
    for r, t, keep, ori, s, w in loaded:
        lab = rd.label(r)
        c = col[lab]
        ls = linestyle(all_labels.index(lab), 10 if len(all_labels) <= 10 else 20)
        sl = _decimate(len(t))
        curves = [ori, s.energy_error if s else None, s.angular_momentum_error if s else None]
        for ax, y in zip(axes[:3], curves):
            if y is None:
                continue
            x, yy = _finite_xy(t[keep][sl], np.asarray(y)[keep][sl], log_y=True)
            h = ax.plot(x, yy, color=c, linestyle=ls, linewidth=1)[0]
            handles.setdefault(lab, h)
        for k in range(3):
            x, yy = _finite_xy(t[keep][sl], w[keep][sl, k])
            axes[3].plot(x, yy, color=c, linestyle=ls, linewidth=1, alpha=0.8)
    return handles


def _draw_truth_angular_velocity(ax, truth) -> None:
    """The truth's world angular velocity components, dashed, with the y range fitted to them."""
    tt = truth.t
    sl = _decimate(len(tt))
    for k in range(3):
        x, yy = _finite_xy(tt[sl], truth.angular_velocity[sl, k])
        ax.plot(x, yy, **TRUTH_STYLE)
    w_true = truth.angular_velocity[np.all(np.isfinite(truth.angular_velocity), axis=1)]
    if len(w_true):
        lo, hi = float(w_true.min()), float(w_true.max())
        pad = max(0.25 * (hi - lo), 0.1 * max(abs(lo), abs(hi)), 1e-3)
        ax.set_ylim(lo - pad, hi + pad)  # a blown-up run must not flatten the truth


def _style_case_panels(axes: list, physics: rd.CasePhysics | None) -> None:
    """Titles, labels and grids of case_dt's panels; the three error panels on log axes capped at
    LOG_PANEL_TOP, or a note where there is nothing to draw."""
    titles = ("orientation error (rad)", "energy error (rel. to max KE)",
              "angular momentum error (rel. to max |L|)", "world angular velocity (rad/s); truth dashed")
    for k, (ax, title) in enumerate(zip(axes, titles)):
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
        if k < 3:
            if any(len(ln.get_xdata()) for ln in ax.lines):
                _log_axes(ax, y=True)
                if ax.get_ylim()[1] > LOG_PANEL_TOP:  # a blow-up must not squash the other runs
                    ax.set_ylim(top=LOG_PANEL_TOP)
            else:
                _empty(ax, "needs the case's mass and inertia" if physics is None and k in (1, 2)
                       else "no positive finite error to draw on a log axis")
