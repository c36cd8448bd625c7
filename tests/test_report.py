"""Reports: `freebody run` writes report.md/report.html and the fitted orders; `freebody report`
re-renders them; the HTML embeds its images and parses; every status renders without a NaN; the
observed-order fit and its saturation rules."""
from __future__ import annotations

import base64
import copy
import json
import math
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest

from freebody.cli import main
from freebody.run.convergence import fit_orders
from freebody.tolerances import CONVERGENCE_ORIENTATION_FLOOR_RAD as ORIENTATION_FLOOR_RAD
from freebody.report.render import write_reports

ORDER_ATOL = 1e-9  # errors made exactly C dt^p: the least-squares fit returns p to round-off
SAME_STATE_RAD = 1e-15  # geodesic angle of a quaternion to itself: normalisation round-off only
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CONVERGENCE_KEYS = {"case", "engine", "integrator", "precision", "metric", "order", "dts", "reason"}
# report.html of the tiny run: heat map, convergence, speed-accuracy + one figure per case and dt
FRONT_FIGURES = 3


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report_run")
    code = main(["run", "quiz", "dzhanibekov", "--engine", "reference", "--integrator", "euler-quat",
                 "--integrator", "rk4", "--duration", "0.1", "--dt", "0.02", "--dt", "0.01", "--dt", "0.005",
                 "--out", str(out), "--quiet"])
    assert code == 0
    return out


class _Collector(HTMLParser):
    VOID = {"meta", "img", "br", "hr", "link", "input"}

    def __init__(self):
        super().__init__()
        self.images, self.links, self.stack, self.errors = [], [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src", ""))
        for k in ("src", "href"):
            if a.get(k):
                self.links.append(a[k])
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes <{self.stack[-1] if self.stack else None}>")
        else:
            self.stack.pop()


def parse_html(text: str) -> _Collector:
    p = _Collector()
    p.feed(text)
    p.close()
    return p


def test_run_writes_reports_and_convergence(run_dir):
    doc = json.loads((run_dir / "results.json").read_text())
    assert (run_dir / "report.md").is_file() and (run_dir / "report.html").is_file()
    conv = doc["convergence"]
    assert {(e["case"], e["integrator"], e["metric"]) for e in conv} == {
        (c, i, m) for c in ("quiz", "dzhanibekov") for i in ("euler-quat", "rk4")
        for m in ("orientation_error_max_rad", "energy_error_max_rel")}
    for e in conv:
        assert CONVERGENCE_KEYS <= set(e)
        assert e["dts"] == [0.005, 0.01, 0.02]
        assert (e["order"] is None) == (e["reason"] is not None and e["reason"].startswith(("saturated", "too few")))
    quiz_rk4 = [e for e in conv if e["case"] == "quiz" and e["integrator"] == "rk4"
                and e["metric"] == "energy_error_max_rel"][0]
    assert quiz_rk4["order"] is None and quiz_rk4["saturated"]  # errors at round-off: no order
    assert doc["cases"]["dzhanibekov"]["inertia"] == [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]
    md = (run_dir / "report.md").read_text()
    assert "## Case `dzhanibekov`" in md and "saturated" in md


def test_html_embeds_its_images_and_parses(run_dir):
    html = (run_dir / "report.html").read_text()
    p = parse_html(html)
    assert p.errors == [] and p.stack == []
    n_case_dt = 2 * 3
    assert len(p.images) == FRONT_FIGURES + n_case_dt
    for src in p.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1]).startswith(PNG_MAGIC)
    external = [u for u in p.links if not u.startswith(("data:", "#"))]
    assert external == [], "report.html must open offline"


def test_report_command_rerenders_the_same_markdown(run_dir):
    before = (run_dir / "report.md").read_text()
    (run_dir / "report.md").unlink()
    (run_dir / "report.html").unlink()
    assert main(["report", str(run_dir), "--markdown-only"]) == 0
    assert (run_dir / "report.md").read_text() == before
    assert not (run_dir / "report.html").exists()


def test_report_command_bad_input_is_one_line_exit_2(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    (tmp_path / "results.json").write_text('{"schema_version": 99, "runs": []}')
    assert main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "schema_version" in err[1]


def test_every_status_renders_without_nan(run_dir, tmp_path):
    doc = json.loads((run_dir / "results.json").read_text())
    runs = [r for r in doc["runs"] if r["case"] == "dzhanibekov"]
    ok = runs[0]
    extra = []
    for status, msg in (("diverged", "diverged at t = 0.05 s: state is not finite"),
                        ("failed", "RuntimeError: boom"), ("skipped", "mujoco not installed")):
        r = copy.deepcopy(ok)
        r.update(engine="mujoco", integrator="Euler", status=status, message=msg, final_state=None,
                 metrics={k: math.nan for k in ok["metrics"]}, trajectory=None, diverged_at_s=0.05)
        extra.append(r)
    f32 = copy.deepcopy(ok)
    f32.update(engine="mujoco", integrator="Euler", precision="float32", wall_time_s=math.inf,
               engine_settings={"timestep": {"default": 0.002, "set": ok["dt"]}, "odd": [1.0, math.nan]},
               matches_reference={"integrator": None, "closest": "semi-implicit-explicit-gyro",
                                  "max_orientation_diff_rad": math.nan})
    f32["metrics"]["energy_error_max_rel"] = math.nan
    doc = {**doc, "runs": runs + extra + [f32], "engines": {"reference": "0.1.0", "mujoco": None}}
    doc.pop("convergence")
    out = tmp_path / "mixed"
    for r in runs:
        (out / r["trajectory"]).parent.mkdir(parents=True, exist_ok=True)
        (out / r["trajectory"]).write_bytes((run_dir / r["trajectory"]).read_bytes())
    f32["trajectory"] = runs[0]["trajectory"]
    md_path, html_path = write_reports(out, doc)
    md, html = md_path.read_text(), html_path.read_text()
    for text in (md, html):
        assert not re.search(r"\bnan\b|\binf\b", text, re.IGNORECASE)
    assert "mujoco/Euler/float32" in md and "RuntimeError: boom" in md
    assert "| reference/euler-quat" in md and "not installed" in md
    # the engine-vs-engine table compares the float32 run with the reference runs at its dt
    assert re.search(r"\| reference/\S+ +\| mujoco/Euler/float32", md) is None  # precisions differ: no pair
    p = parse_html(html)
    assert p.errors == [] and all(s.startswith("data:image/png;base64,") for s in p.images)


def test_engine_pairs_report_final_state_differences(run_dir, tmp_path):
    doc = json.loads((run_dir / "results.json").read_text())
    ref = [r for r in doc["runs"] if r["case"] == "dzhanibekov" and r["integrator"] == "rk4"]
    twins = [{**copy.deepcopy(r), "engine": "twin", "integrator": "rk4-copy", "trajectory": None} for r in ref]
    doc = {**doc, "runs": ref + twins}
    (md_path,) = write_reports(tmp_path, doc, html=False)
    rows = [ln.split("|")[1:-1] for ln in md_path.read_text().splitlines() if "| twin/rk4-copy |" in ln]
    pairs = [[c.strip() for c in row] for row in rows if row[1].strip() == "reference/rk4"]
    assert len(pairs) == 3  # one per dt
    for dt, a, b, angle, dL, dE, relation in pairs:  # identical final states
        assert float(angle) < SAME_STATE_RAD and float(dL) == 0.0 and float(dE) == 0.0
        assert relation == "-"  # the twin's scheme was not identified: no relation claimed


# --- the order fit --------------------------------------------------------------------------------

def _runs(errors: dict[float, float | None], status: dict[float, str] | None = None, precision="float64"):
    return [{"case": "c", "engine": "e", "integrator": "i", "precision": precision, "dt": dt, "steps": round(1 / dt),
             "status": (status or {}).get(dt, "ok"),
             "metrics": {"orientation_error_max_rad": err, "energy_error_max_rel": err}}
            for dt, err in errors.items()]


def _orient(entries):
    return [e for e in entries if e["metric"] == "orientation_error_max_rad"][0]


@pytest.mark.parametrize("p", [1.0, 2.0, 4.0])
def test_fit_recovers_the_order_of_exact_power_laws(p):
    e = _orient(fit_orders(_runs({dt: 3.0 * dt ** p for dt in (0.04, 0.02, 0.01)})))
    assert abs(e["order"] - p) < ORDER_ATOL and e["reason"] is None and not e["saturated"]


def test_fit_leaves_out_saturated_points_and_says_so():
    # one point of order pi, three on a first-order line: fitted on the three
    e = _orient(fit_orders(_runs({0.08: 3.0, 0.04: 0.04, 0.02: 0.02, 0.01: 0.01})))
    assert abs(e["order"] - 1.0) < ORDER_ATOL and e["fitted_dts"] == [0.01, 0.02, 0.04]
    assert "saturated above 1" in e["reason"]
    # at the truth's floor: no order
    e = _orient(fit_orders(_runs({0.04: 1e-10, 0.02: 1e-11, 0.01: 1e-12})))
    assert e["order"] is None and e["saturated"] and "floor" in e["reason"]
    # all of order pi: no order
    e = _orient(fit_orders(_runs({0.04: 3.0, 0.02: 2.5, 0.01: 2.0})))
    assert e["order"] is None and e["saturated"] and "order pi" in e["reason"]
    # float32: its floor is higher
    e = _orient(fit_orders(_runs({0.04: 4e-6, 0.02: 2e-6, 0.01: 1e-6}, precision="float32")))
    assert e["order"] is None and e["saturated"]
    assert _orient(fit_orders(_runs({0.04: 4e-6, 0.02: 2e-6, 0.01: 1e-6})))["order"] is not None
    assert 4e-6 > ORIENTATION_FLOOR_RAD


def test_fit_skips_runs_that_are_not_ok_and_groups_with_fewer_than_three_dts():
    e = _orient(fit_orders(_runs({0.04: 0.04, 0.02: None, 0.01: 0.01}, status={0.02: "diverged"})))
    assert e["order"] is None and not e["saturated"] and "0.02 (diverged)" in e["reason"]
    assert fit_orders(_runs({0.02: 0.02, 0.01: 0.01})) == []
    e = _orient(fit_orders(_runs({0.04: math.nan, 0.02: 0.02, 0.01: 0.01})))
    assert e["order"] is None and e["errors"][-1] is None


STATUS_MESSAGES = {"failed": "OSError: libengine.so.4: cannot open shared object file",
                   "skipped": "broken is not installed: pip install broken",
                   "diverged": "diverged at t = 0.05 s: state is not finite"}


def _not_ok(run: dict, status: str, engine: str) -> dict:
    r = copy.deepcopy(run)
    r.update(engine=engine, status=status, message=STATUS_MESSAGES[status], final_state=None, trajectory=None,
             metrics={} if status != "diverged" else {k: math.nan for k in run["metrics"]},
             matches_reference=None, diverged_at_s=0.05 if status == "diverged" else None)
    return r


SUBSETS = [("failed",), ("skipped",), ("diverged",), ("failed", "skipped"), ("failed", "diverged"),
           ("skipped", "diverged"), ("failed", "skipped", "diverged")]


@pytest.mark.parametrize("statuses, others_ok", [(s, False) for s in SUBSETS] + [(SUBSETS[-1], True)],
                         ids=[f"{'+'.join(s)}-no-ok-run" for s in SUBSETS] + ["all-beside-ok-runs"])
def test_any_subset_of_failed_skipped_diverged_runs_renders(run_dir, tmp_path, statuses, others_ok):
    """Every run of an engine not ok (a convergence case, three time steps, where all of them failed,
    were skipped or diverged, in any mix), beside ok runs of another engine or with none at all:
    both reports render (figures included), without a NaN, naming each reason."""
    doc = json.loads((run_dir / "results.json").read_text())
    ok = doc["runs"]
    broken = [_not_ok(r, statuses[i % len(statuses)], "broken") for i, r in enumerate(ok)]
    runs = (ok if others_ok else [_not_ok(r, statuses[-1 - i % len(statuses)], "reference")
                                  for i, r in enumerate(ok)]) + broken
    doc = {**doc, "runs": runs, "engines": {"reference": doc["engines"]["reference"], "broken": None}}
    doc.pop("convergence", None)
    out = tmp_path / "out"
    for r in runs:
        if r.get("trajectory"):
            (out / r["trajectory"]).parent.mkdir(parents=True, exist_ok=True)
            (out / r["trajectory"]).write_bytes((run_dir / r["trajectory"]).read_bytes())
    md_path, html_path = write_reports(out, doc)
    md, html = md_path.read_text(), html_path.read_text()
    for text in (md, html):
        assert not re.search(r"\bnan\b|\binf\b", text, re.IGNORECASE)
        for s in statuses:
            assert STATUS_MESSAGES[s] in text
    p = parse_html(html)
    assert p.errors == [] and len(p.images) >= 1 and all(s.startswith("data:image/png;base64,") for s in p.images)
