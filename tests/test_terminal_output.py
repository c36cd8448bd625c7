"""Issue 21, items 3 and 6: what ``freebody run`` prints on the terminal.

- 3: a summary that fits an 80 x 50 terminal for the default suite (a matrix of cases x engines
  with the worst orientation error and a status marker, the runs that are not ok grouped, at most
  10 lines of them), the full per-run table only with ``--table``, and last lines saying what to
  open first;
- 6: one progress display for ``run`` and ``sweep``: on a terminal one line rewritten at most ~10
  times a second with done/total, percentage, elapsed time, ETA and the last run; elsewhere plain
  lines (no carriage return) after the first run, every tenth of the runs or 10 s, and the last.
"""
from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest

from freebody.cli import main
from freebody.results.document import complete_run
from freebody.input.casefile import bundled_case_paths
from freebody.report.summary import (MATRIX_TITLE, NOT_OK_LINES_MAX, not_ok_lines, summary_matrix,
                                     summary_width, terminal_summary, where_to_look)
from freebody.run.progress import (ETA_MIN_DONE, LOG_INTERVAL_S, TTY_INTERVAL_S, ProgressDisplay,
                                   estimate_eta, format_duration, format_eta, progress_line)

SCREEN_COLUMNS, SCREEN_LINES = 80, 50  # the terminal the summary of the default suite must fit
ESC = "\x1b"
REWRITE = "\r\x1b[K"  # what starts each rewrite of the progress line on a terminal


# --- fakes ------------------------------------------------------------------------------------------

class FakeClock:
    """A monotonic clock the test advances by hand (seconds)."""

    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


class Tty(io.StringIO):
    """A terminal: ``isatty()`` is true; counts the flushes."""

    flushes = 0

    def isatty(self) -> bool:
        return True

    def flush(self) -> None:
        self.flushes += 1


def _run(case: str, engine: str, integrator: str, dt: float = 0.01, status: str = "ok", err=1e-3,
         message: str = "", precision: str = "float64", diverged_at: float | None = None) -> dict:
    """A results.json ``runs`` entry with what the summary reads, in the newest shape (its
    judgement included, as every run the summary is given has one)."""
    return complete_run({"case": case, "engine": engine, "integrator": integrator, "dt": dt, "status": status,
            "precision": precision, "message": message, "diverged_at_s": diverged_at,
            "metrics": {"orientation_error_max_rad": err} if status == "ok" else {},
            "matches_reference": None, "vs_engine": None})


# The default suite as measured (freebody run, every default engine installed: 1161 runs): the
# engine columns with their precision and number of integrators; every case at two time steps.
DEFAULT_SUITE_COLUMNS = [("reference", "float64", 10), ("mujoco", "float64", 5), ("pybullet", "float64", 2),
                         ("dart", "float64", 1), ("mjx", "float32", 3), ("mjx", "float64", 3),
                         ("drake", "float64", 1), ("sapien", "float32", 2)]


@pytest.fixture(scope="module")
def default_suite_runs() -> list[dict]:
    rng = np.random.default_rng(21)
    runs = []
    for case in bundled_case_paths():
        for engine, precision, n in DEFAULT_SUITE_COLUMNS:
            for i in range(n):
                for dt in (0.01, 0.001):
                    runs.append(_run(case, engine, f"scheme{i}", dt, err=float(10 ** rng.uniform(-15, 0.5)),
                                     precision=precision))
    # a realistic spread of trouble: one scheme diverging on many cases, a few failures
    for r in runs:
        if r["engine"] == "reference" and r["integrator"] == "scheme0" and r["dt"] == 0.01:
            r.update(status="diverged", metrics={}, diverged_at_s=float(rng.uniform(0.01, 6)),
                     message=f"diverged at t = {r['dt']} s: R is no rotation: ||R^T R - 1||_F beyond 1")
        if r["engine"] == "sapien" and r["case"] in ("quiz", "projectile"):
            r.update(status="failed", metrics={}, message="RuntimeError: PhysX: invalid inertia")
    return runs


# --- 6. progress: pure formatting -------------------------------------------------------------------

@pytest.mark.parametrize("seconds, text", [
    (0, "0:00"), (0.99, "0:00"), (7.5, "0:07"), (59.999, "0:59"), (61, "1:01"), (754, "12:34"),
    (3600, "1:00:00"), (3725.2, "1:02:05"), (100 * 3600, "100:00:00"),
    (None, "--"), (float("nan"), "--"), (float("inf"), "--"), (-1.0, "--"),
])
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text


def test_format_eta_says_unknown_until_known():
    assert format_eta(None) == "ETA --"
    assert format_eta(83.0) == "ETA 1:23"
    assert format_eta(0.0) == "ETA 0:00"


def test_eta_is_the_rate_of_the_finished_runs_after_a_few():
    assert ETA_MIN_DONE >= 2
    assert estimate_eta(ETA_MIN_DONE - 1, 100, 5.0) is None  # too few runs to trust a rate
    assert estimate_eta(4, 10, 8.0) == pytest.approx(12.0)  # 2 s a run, 6 runs left
    assert estimate_eta(10, 10, 8.0) == 0.0
    assert estimate_eta(5, 10, 0.0) is None  # no time measured yet


def test_progress_line_fields():
    assert progress_line(123, 774, 5.2, "ok       dzhanibekov mujoco/Euler dt=0.01") == (
        "[123/774 runs]  15%  0:05 elapsed  ETA 0:27  ok       dzhanibekov mujoco/Euler dt=0.01")
    assert progress_line(1, 774, 0.4, "x").startswith("[1/774 runs]   0%  0:00 elapsed  ETA --  x")
    assert progress_line(773, 774, 60, "x", unit="").startswith("[773/774]  99%")  # never 100% too early
    assert progress_line(774, 774, 61, "x").startswith("[774/774 runs] 100%  1:01 elapsed  ETA 0:00")
    assert ESC not in progress_line(1, 2, 0, f"c{ESC}[2J")


# --- 6. progress: the display on a terminal ---------------------------------------------------------

def test_terminal_line_is_rewritten_with_eta_and_the_last_run():
    clock, out = FakeClock(), Tty()
    bar = ProgressDisplay(10, stream=out, clock=clock)
    for i in range(4):
        clock.t += 2.0
        bar.update(f"ok run{i}")
    shown = out.getvalue().split(REWRITE)
    assert shown[0] == "" and len(shown) == 5 and "\n" not in out.getvalue()
    assert shown[1] == "[1/10 runs]  10%  0:02 elapsed  ETA --  ok run0"
    assert shown[ETA_MIN_DONE - 1].endswith("ETA --  ok run%d" % (ETA_MIN_DONE - 2))
    assert shown[4] == "[4/10 runs]  40%  0:08 elapsed  ETA 0:12  ok run3"


def test_terminal_updates_are_throttled_and_the_last_always_shown():
    clock, out = FakeClock(), Tty()
    n = 1000
    bar = ProgressDisplay(n, stream=out, clock=clock)
    t0 = clock.t
    for i in range(n):
        clock.t = t0 + (i + 1) * 0.001  # 1000 runs a second: no line per run
        bar.update(f"run{i}")
    rewrites = out.getvalue().count(REWRITE)
    assert rewrites <= n * 0.001 / TTY_INTERVAL_S + 2 and out.flushes == rewrites
    assert out.getvalue().endswith(f"[{n}/{n} runs] 100%  0:01 elapsed  ETA 0:00  run{n - 1}\n")


def test_a_note_brings_the_held_back_line_up_to_date_and_ends_it():
    clock, out = FakeClock(), Tty()
    bar = ProgressDisplay(5, stream=out, clock=clock)
    bar.update("first")
    clock.t += TTY_INTERVAL_S / 10
    bar.update("second")  # held back by the throttle
    assert "second" not in out.getvalue()
    bar.note("Ctrl-C: 2 of 5 runs finished")
    assert out.getvalue().endswith("ETA --  second\nCtrl-C: 2 of 5 runs finished\n")


def test_terminal_line_is_cut_to_the_width():
    clock, out = FakeClock(), Tty()
    bar = ProgressDisplay(2, stream=out, clock=clock)
    bar.update("x" * 500)
    line = out.getvalue().split(REWRITE)[1]
    assert len(line) == 79  # a StringIO has no terminal size: 80 columns, less one (no wrap)


# --- 6. progress: plain lines in a log --------------------------------------------------------------

def test_log_lines_at_the_first_every_tenth_and_the_last_never_a_carriage_return():
    clock, out = FakeClock(), io.StringIO()
    bar = ProgressDisplay(95, stream=out, clock=clock)
    for i in range(95):
        clock.t += 0.01
        bar.update(f"run{i}")
    text = out.getvalue()
    assert "\r" not in text and ESC not in text
    counts = [int(re.match(r"\[(\d+)/95 runs\]", ln).group(1)) for ln in text.splitlines()]
    assert counts == [1, 10, 20, 30, 40, 50, 60, 70, 80, 90, 95]


def test_log_lines_every_10_s_when_runs_are_slow():
    clock, out = FakeClock(), io.StringIO()
    bar = ProgressDisplay(1000, stream=out, clock=clock)
    for i in range(30):
        clock.t += 3.0
        bar.update(f"run{i}")
    counts = [int(re.match(r"\[(\d+)/", ln).group(1)) for ln in out.getvalue().splitlines()]
    assert counts == [1, 5, 9, 13, 17, 21, 25, 29]  # 3 s a run: a line when 10 s have passed


def test_log_every_and_disabled():
    clock, out = FakeClock(), io.StringIO()
    bar = ProgressDisplay(5, "bodies", stream=out, every=2, clock=clock)
    for i in range(5):
        bar.update(f"b{i}")
    assert [ln.split()[0] + " " + ln.split()[1] for ln in out.getvalue().splitlines()] == [
        "[1/5 bodies]", "[2/5 bodies]", "[4/5 bodies]", "[5/5 bodies]"]
    quiet = Tty()
    off = ProgressDisplay(3, stream=quiet, enabled=False)
    off.update("x")
    off.note("y")
    assert quiet.getvalue() == "" and off.done == 1


# --- 3. the summary -----------------------------------------------------------------------------------

def test_default_suite_summary_fits_an_80_by_50_terminal(default_suite_runs):
    text = terminal_summary(default_suite_runs, SCREEN_COLUMNS)
    last = where_to_look("reports/latest", ["reports/latest/report.md", "reports/latest/report.html"])
    screen = (text + "\n\n" + last).splitlines()
    assert len(default_suite_runs) > 800
    assert len(screen) <= SCREEN_LINES, "\n".join(screen)
    assert max(len(ln) for ln in screen) <= SCREEN_COLUMNS, "\n".join(ln for ln in screen if len(ln) > 80)
    for case in bundled_case_paths():  # every case has its row
        assert any(ln.startswith(case + " ") for ln in screen), case
    first_row = next(i for i, ln in enumerate(screen) if ln.startswith("body_torque_spinup "))
    header = " ".join(screen[1:first_row]).split()
    assert sorted(header) == sorted(["case", "reference", "mujoco", "pybullet", "dart", "mjx/float32", "mjx",
                                     "drake", "sapien/float32"])


@pytest.mark.slow
def test_the_real_default_suite_fits_too():
    """The default suite as expand() builds it today (every default engine, installed or not)."""
    from freebody.input.casefile import load_case
    from freebody.run import expand, select_engines

    specs = expand([load_case(n) for n in bundled_case_paths()], select_engines(None), None, None, None)
    runs = [_run(s.problem.name, s.engine, s.integrator, s.dt, precision=s.precision, err=0.123) for s in specs]
    screen = (terminal_summary(runs) + "\n\n" + where_to_look("reports/latest", [])).splitlines()
    assert len(screen) <= SCREEN_LINES and max(len(ln) for ln in screen) <= SCREEN_COLUMNS, "\n".join(screen)


def test_matrix_cells_worst_error_markers_and_words():
    runs = [_run("a", "e1", "i1", err=1e-3), _run("a", "e1", "i2", err=2.5e-2), _run("a", "e1", "i1", 0.001, err=7e-9),
            _run("a", "e2", "i1", err=3e-1), _run("a", "e2", "i2", status="diverged", message="boom"),
            _run("b", "e1", "i1", err=0.0), _run("b", "e1", "i2", status="failed", message="bad"),
            _run("b", "e2", "i1", status="diverged"), _run("b", "e2", "i2", status="failed")]
    lines = summary_matrix(runs)
    assert lines == [MATRIX_TITLE,
                     "case       e1        e2",
                     "a     2.5e-02   3.0e-01d",
                     "b           0F     FAIL",
                     "F: a run failed; d: a run diverged; FAIL/div/skip: no run ok"]


def _grown(run: dict, growth: dict) -> dict:
    """``run`` with this ``state_growth``, judged again (its judgement is what the summary reads)."""
    return complete_run({**{k: v for k, v in run.items() if k != "judgement"}, "state_growth": growth})


def test_a_blow_up_and_a_rotation_cap_are_marked_apart_from_a_saturated_phase_error():
    """Three cells at ~3.1 rad: a phase error (no marker), a blow-up (b), a blow-up past the engine's
    rotation cap (b and c), each marker with its legend; a diverged run's growth is not marked."""
    grown = {"blow_up_t_s": 2.51, "omega_ratio": 797.0, "kinetic_energy_ratio": 6.5e3}
    runs = [_run("disk", "e1", "implicit", err=3.13),
            _grown(_run("disk", "e2", "euler", err=3.11), grown),
            _grown(_run("disk", "e3", "multibody", err=3.12),
                   {**grown, "step_rotation_cap_rad": 0.785, "rotation_cap_t_s": 1.39}),
            _grown(_run("disk", "e4", "x", status="diverged"), grown),
            _grown(_run("disk", "e4", "y", err=3.1), {"blow_up_t_s": None})]
    lines = summary_matrix(runs)
    row = next(ln for ln in lines if ln.startswith("disk"))
    assert row.split() == ["disk", "3.1e+00", "3.1e+00b", "3.1e+00bc", "3.1e+00d"], row
    legend = "; ".join(lines[lines.index(row) + 1:])
    assert "b: blow-up (|w| > 20x or KE > 10x the truth's)" in legend
    assert "c: |w| dt beyond the engine's rotation cap a step" in legend
    # results written before state_growth: no marker, no legend
    old = [_run("disk", "e1", "implicit", err=3.13), _run("disk", "e2", "euler", err=3.11)]
    assert not any(ln.startswith(("b:", "c:")) for ln in summary_matrix(old))


def test_an_engine_with_every_run_skipped_gets_no_column_and_precision_makes_a_column():
    runs = [_run("a", "ref", "rk4"), _run("a", "gone", "*", status="skipped", message="not installed"),
            _run("a", "mjx", "Euler", precision="float32", err=2e-3), _run("a", "mjx", "Euler", err=1e-4)]
    lines = summary_matrix(runs)
    assert lines[1].split() == ["case", "ref", "mjx/float32", "mjx"]  # room for the labels: on one line
    assert lines[2].split() == ["a", "1.0e-03", "2.0e-03", "1.0e-04"]
    assert lines[-1] == "no column: gone (every run skipped)"


def test_labels_that_do_not_fit_are_staggered_over_their_values():
    engines = ["reference", "mujoco", "pybullet", "dart", "mjx/float32", "drake", "sapien", "genesis"]
    runs = [_run(c, e.split("/")[0], "i", err=1e-3, precision="float32" if "/" in e else "float64")
            for c in ("case_number_one", "case_number_two") for e in engines]
    lines = summary_matrix(runs, 60)
    assert all(len(ln) <= 60 for ln in lines), "\n".join(lines)
    first_row = next(i for i, ln in enumerate(lines) if ln.startswith("case_number_one "))
    header = lines[1:first_row]
    assert 2 <= len(header) <= 3 and sorted(" ".join(header).split()) == sorted(["case", *engines])
    values = lines[first_row].split()[1:]
    assert values == ["1e-3"] * len(engines)  # one digit is what fits
    for k, label in enumerate(engines):  # each label ends over the last digit of its column
        line = header[k % len(header)]
        end = re.search(rf"(?<!\S){re.escape(label)}(?!\S)", line).end()
        assert lines[first_row][end - 1] == "3", (label, lines)
    assert all(ln.split()[1:] == values for ln in lines[first_row:first_row + 2])


def test_not_ok_runs_grouped_by_engine_and_reason_failed_first():
    runs = [_run(f"c{i}", "reference", "euler", status="diverged", diverged_at=t,
                 message=f"diverged at t = {t} s: R is no rotation") for i, t in enumerate((0.5, 2.0, 1.25))]
    runs += [_run("c0", "dart", "semi-implicit-euler", status="failed", message="ImportError: libdart.so")]
    runs += [_run("c0", "pybullet", "*", status="skipped", message="pybullet is not installed")]
    runs += [_run("c1", "reference", "rk4")]
    runs += [_run("c2", "dart", "semi-implicit-euler", status="failed", message="ImportError: libdart.so, "
                  "a long message about a broken installation")]
    assert not_ok_lines(runs) == [
        "not ok: 6 runs (each one: report.md, or freebody run --table)",
        "  dart/semi-implicit-euler: 1 failed in c0: ImportError: libdart.so",
        "  dart/semi-implicit-euler: 1 failed in c2",  # too long for a line: the reason on the next
        "    ImportError: libdart.so, a long message about a broken installation",
        "  reference/euler: 3 diverged in 3 cases, at t = 0.5 to 2 s: R is no rotation",
        "  pybullet: 1 skipped in c0: pybullet is not installed"]
    assert not_ok_lines([_run("c", "e", "i")]) == []


def test_not_ok_list_is_at_most_10_lines_then_and_n_more():
    runs = [_run("c", f"engine{i}", "i", status="failed", message=f"error {i} " + "x" * (10 if i % 2 else 90))
            for i in range(20)]
    lines = not_ok_lines(runs)
    assert len(lines) - 1 <= NOT_OK_LINES_MAX and all(len(ln) <= 80 for ln in lines)
    shown = sum(1 for ln in lines if re.match(r"  engine\d+/i: 1 failed", ln))
    assert lines[-1] == f"  and {20 - shown} more groups ({20 - shown} runs)"
    assert 3 <= shown < 10
    nan = "diverged at t = 0.43 s: state is not finite (NaN or inf)"
    diverged = [_run("high_spin_dt_10ms", "mjx", x, status="diverged", diverged_at=0.43, precision="float32",
                     message=nan) for x in ("Euler", "implicitfast")]
    assert not_ok_lines(diverged)[1:] == ["  mjx/float32/{Euler,implicitfast}: 2 diverged in high_spin_dt_10ms",
                                          "    at t = 0.43 s: state is not finite (NaN or inf)"]
    long_names = [_run("c" * 100, "engine", "i" * 90, status="failed", message="m" * 200)]
    assert all(len(ln) <= 80 for ln in not_ok_lines(long_names)), not_ok_lines(long_names)


def test_summary_escapes_names_and_messages():
    runs = [_run(f"c{ESC}[31m", "reference", "rk4"),
            _run(f"c{ESC}[31m", "reference", "euler", status="failed", message=f"engine said {ESC}[2J\nagain")]
    text = terminal_summary(runs)
    assert ESC not in text and "\n" + "again" not in text
    assert "c\\x1b[31m" in text and "engine said \\x1b[2J\\nagain" in text


def test_where_to_look_names_what_to_open_first():
    assert where_to_look("reports/latest", ["reports/latest/report.md", "reports/latest/report.html"]) == (
        "open reports/latest/report.html (start with the findings at the top)\n"
        "tables: reports/latest/report.md\n"
        "data: reports/latest/results.json")
    assert where_to_look("my out", []) == (
        "reports: not written; freebody report 'my out' writes them\ndata: my out/results.json")


def test_summary_width_is_80_off_a_terminal():
    assert summary_width(io.StringIO()) == 80
    assert summary_width(Tty()) == 80  # a terminal that does not say its size


# --- 3. freebody run prints the summary, the table only with --table --------------------------------

def test_run_prints_the_summary_and_where_to_look_last(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", "quiz", "projectile", "--engine", "reference", "--dt", "0.01", "--out", str(out),
                 "--quiet", "--no-report"])
    printed = capsys.readouterr().out
    runs = json.loads((out / "results.json").read_text())["runs"]
    assert code == 0 and len(runs) > 10
    lines = printed.splitlines()
    assert lines[0] == MATRIX_TITLE
    assert [ln.split()[0] for ln in lines[2:4]] == ["quiz", "projectile"]
    assert "engine/integrator" not in printed  # no per-run table
    assert "reference/euler-matrix: 1 diverged in projectile" in printed
    assert lines[-4].endswith("skipped (%d runs)" % len(runs)) and lines[-3] == ""
    assert lines[-2:] == [f"reports: not written; freebody report {out} writes them", f"data: {out / 'results.json'}"]
    assert len(lines) < 20


def test_run_table_flag_prints_every_run(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", "quiz", "--engine", "reference", "--dt", "0.01", "--out", str(out), "--quiet", "--table"]) == 0
    printed = capsys.readouterr().out
    runs = json.loads((out / "results.json").read_text())["runs"]
    rows = [ln for ln in printed.splitlines() if ln.startswith("quiz ")]
    assert len(rows) == len(runs) + 1  # one row a run in the table, one in the matrix
    assert printed.index("engine/integrator") < printed.index(MATRIX_TITLE)  # the summary stays last
    tail = printed.splitlines()[-3:]
    assert tail == [f"open {out / 'report.html'} (start with the findings at the top)",
                    f"tables: {out / 'report.md'}", f"data: {out / 'results.json'}"]


def test_a_failed_run_is_in_the_summary_and_exits_1(tmp_path, capsys, monkeypatch):
    from fake_engines.crashing_adapter import REGISTRY_ENTRY
    from freebody.adapters.base import ENGINES

    monkeypatch.setitem(ENGINES, "crasher", REGISTRY_ENTRY)
    code = main(["run", "dzhanibekov", "--engine", "reference", "--engine", "crasher", "--integrator",
                 "reference:rk4", "--integrator", "crasher:exit", "--dt", "0.01", "--duration", "0.05",
                 "--no-isolation", "--out", str(tmp_path), "--quiet", "--no-report"])
    printed = capsys.readouterr().out
    assert code == 1
    row = next(ln for ln in printed.splitlines() if ln.startswith("dzhanibekov "))
    assert row.split()[-1] == "FAIL"
    assert "  crasher/exit: 1 failed in dzhanibekov" in printed and "SystemExit: 4" in printed


def test_where_to_look_opens_the_report_not_its_tables_page():
    """A long report also writes report-tables.html (written before report.html): the line says
    to open report.html."""
    last = where_to_look("reports/latest", ["reports/latest/report.md", "reports/latest/report-tables.html",
                                            "reports/latest/report.html"])
    assert last.splitlines()[0] == "open reports/latest/report.html (start with the findings at the top)", last
