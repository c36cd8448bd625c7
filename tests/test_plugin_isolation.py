"""Plug-ins cannot stall freebody (issue 28 item 2).

Each plug-in here is a real distribution on ``sys.path`` (a ``*.dist-info`` folder with METADATA and
entry_points.txt beside its module, as ``tests/fake_engines/plugin_site``), and freebody runs in a
child process that sees it through ``PYTHONPATH``.  A plug-in's module is imported in a probe
process under the import limit (``run --timeout``, else ``$FREEBODY_PLUGIN_IMPORT_TIMEOUT``, else
``freebody.tolerances.PLUGIN_IMPORT_TIMEOUT_S``): one that hangs, crashes or exits at import gives
failed runs with the reason, and the other engines' runs finish.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from freebody.adapters import base

PLUGIN_IMPORT_LIMIT_S = 3  # the import limit the tests give (env var or --timeout): short, > a probe's start
RUN_TIMEOUT_S = 5  # the --timeout of the hang test (the reproduction used 20)
# A child freebody that takes longer than this has stalled: a run of 2 reference runs and one
# plug-in takes 5-15 s on the loaded 2-core CI machine; the hang sleeps 600 s
STALL_S = 50
HANG = "import time\ntime.sleep(600)\n"
ADAPTER = ("from freebody.adapters.reference import ReferenceAdapter\n\n"
           "class PlugAdapter(ReferenceAdapter):\n    name = {name!r}\n")
# one case, one integrator, two time steps: the fewest runs that exercise a worker
SMALL_RUN = ("quiz", "--integrator", "rk4", "--dt", "0.02", "--duration", "0.1", "--quiet", "--no-report")


def make_plugin(site: Path, name: str, module_text: str) -> Path:
    """A distribution ``freebody-<name>`` whose entry point ``<name>`` is ``<name>_adapter:PlugAdapter``."""
    info = site / f"freebody_{name}-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: freebody-{name}\nVersion: 0.1.0\n")
    (info / "entry_points.txt").write_text(f"[freebody.adapters]\n{name} = {name}_adapter:PlugAdapter\n")
    (site / f"{name}_adapter.py").write_text(module_text + "\n" + ADAPTER.format(name=name))
    return site


def freebody(site: Path, *args, limit: float | None = None) -> tuple[subprocess.CompletedProcess, float]:
    """freebody in a child process with ``site`` on its path; (its result, its wall time, s).
    TimeoutExpired (the test fails) when it stalls."""
    env = {k: v for k, v in os.environ.items() if k != base.PLUGIN_IMPORT_TIMEOUT_ENV}
    env["PYTHONPATH"] = os.pathsep.join([str(site)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if limit is not None:
        env[base.PLUGIN_IMPORT_TIMEOUT_ENV] = str(limit)
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "freebody", *map(str, args)], env=env, capture_output=True,
                          text=True, timeout=STALL_S, stdin=subprocess.DEVNULL)
    return proc, time.monotonic() - t0


def runs_of(out: Path) -> dict[str, list[dict]]:
    doc = json.loads((out / "results.json").read_text())
    by_engine: dict[str, list[dict]] = {}
    for r in doc["runs"]:
        by_engine.setdefault(r["engine"], []).append(r)
    return by_engine


def assert_plugin_failed(out: Path, name: str, reason: str) -> None:
    """The plug-in's runs failed naming it, its entry point and ``reason``; the reference's are ok."""
    runs = runs_of(out)
    assert runs[name] and all(r["status"] == "failed" for r in runs[name]), runs[name]
    for r in runs[name]:
        assert f"plug-in {name}" in r["message"] and f"{name} = {name}_adapter:PlugAdapter" in r["message"]
        assert reason in r["message"], r["message"]
    assert runs["reference"] and all(r["status"] == "ok" for r in runs["reference"])


def test_discovery_imports_no_plugin(tmp_path, monkeypatch):
    """The registry lists a plug-in (a default engine) from its entry point alone."""
    site = make_plugin(tmp_path, "advhang", HANG)
    monkeypatch.syspath_prepend(str(site))
    assert "advhang" in base.registry() and "advhang" in base.default_engine_names()
    assert base.is_available("advhang") and "advhang_adapter" not in sys.modules


def test_a_hanging_plugin_fails_its_runs_within_timeout(tmp_path):
    site = make_plugin(tmp_path / "site", "advhang", HANG)
    proc, wall = freebody(site, "run", *SMALL_RUN, "--engine", "advhang", "--engine", "reference",
                          "--timeout", RUN_TIMEOUT_S, "--out", tmp_path / "out")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert_plugin_failed(tmp_path / "out", "advhang", f"import did not finish within {RUN_TIMEOUT_S} s")
    assert wall < STALL_S


def test_a_hanging_plugin_fails_its_runs_within_the_default_import_limit(tmp_path):
    """No --timeout: the default import limit (here shortened through its environment variable)."""
    site = make_plugin(tmp_path / "site", "advhang", HANG)
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advhang", "--engine", "reference",
                       "--out", tmp_path / "out", limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert_plugin_failed(tmp_path / "out", "advhang", f"import did not finish within {PLUGIN_IMPORT_LIMIT_S} s")


@pytest.mark.parametrize("module_text, reason", [
    ("import os\nos.abort()\n", "import crashed (killed by SIGABRT)"),
    ("import os\nos._exit(3)\n", "import exited with code 3"),
    ("import sys\nsys.exit(3)\n", "import exited (SystemExit: 3)"),
], ids=["abort", "os-exit", "sys-exit"])
def test_a_plugin_that_crashes_or_exits_at_import_fails_its_runs(tmp_path, module_text, reason):
    site = make_plugin(tmp_path / "site", "advbad", module_text)
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advbad", "--engine", "reference",
                       "--out", tmp_path / "out", limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert_plugin_failed(tmp_path / "out", "advbad", reason)


def test_a_plugin_that_raises_at_import_fails_with_its_error(tmp_path):
    site = make_plugin(tmp_path / "site", "advraise", "raise RuntimeError('no licence server')\n")
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advraise", "--engine", "reference",
                       "--out", tmp_path / "out", limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    runs = runs_of(tmp_path / "out")
    assert all(r["status"] == "failed" and "RuntimeError: no licence server" in r["message"]
               for r in runs["advraise"])
    assert all(r["status"] == "ok" for r in runs["reference"])


def test_a_healthy_plugin_still_runs(tmp_path):
    site = make_plugin(tmp_path / "site", "advok", "")
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advok", "--out", tmp_path / "out",
                       limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 0, proc.stderr
    assert all(r["status"] == "ok" for r in runs_of(tmp_path / "out")["advok"])


# A sound plug-in that notes each import: the probe's (python -c) or a real one's, by process
IMPORT_LOG = ("import os, sys\n"
              "with open(os.environ['ADVLOG_FILE'], 'a') as f:\n"
              "    f.write(('probe' if sys.argv[0] == '-c' else 'import') + ' %d\\n' % os.getpid())\n")


def test_a_sound_plugin_is_probed_once_not_once_a_worker(tmp_path, monkeypatch):
    """The parent probes a plug-in once and hands the outcome to its workers (of its own
    interpreter): two workers import it without a probe process each."""
    log = tmp_path / "imports.log"
    monkeypatch.setenv("ADVLOG_FILE", str(log))
    site = make_plugin(tmp_path / "site", "advlog", IMPORT_LOG)
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advlog", "--engine", "reference", "--jobs", "2",
                       "--out", tmp_path / "out", limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 0, proc.stderr
    assert all(r["status"] == "ok" for r in runs_of(tmp_path / "out")["advlog"])
    kinds = [line.split()[0] for line in log.read_text().splitlines()]
    assert kinds.count("probe") == 1, kinds
    assert kinds.count("import") >= 2, kinds  # the parent's and at least one worker's


@pytest.mark.parametrize("args", [
    ("list",),
    ("run", *SMALL_RUN, "--engine", "reference"),
    ("conventions", "--engine", "reference", "--no-checks"),
], ids=["list", "run-reference", "conventions-reference"])
def test_commands_without_the_plugin_never_import_it(tmp_path, args):
    """With the default import limit (a minute): a command that waited for the plug-in would stall."""
    site = make_plugin(tmp_path / "site", "advhang", HANG)
    extra = ("--out", tmp_path / "out") if args[0] == "run" else ()
    proc, wall = freebody(site, *args, *extra)
    assert proc.returncode == 0, proc.stderr
    assert wall < STALL_S


def test_conventions_of_a_hanging_plugin_says_why(tmp_path):
    site = make_plugin(tmp_path / "site", "advhang", HANG)
    proc, _ = freebody(site, "conventions", "--engine", "advhang", "--no-checks", limit=PLUGIN_IMPORT_LIMIT_S)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert f"import did not finish within {PLUGIN_IMPORT_LIMIT_S} s" in proc.stdout


def test_report_never_imports_a_plugin(tmp_path):
    """A results folder with a hanging plug-in's runs reports at once (default import limit)."""
    site = make_plugin(tmp_path / "site", "advhang", HANG)
    proc, _ = freebody(site, "run", *SMALL_RUN, "--engine", "advhang", "--engine", "reference",
                       "--out", tmp_path / "out", limit=1)
    assert proc.returncode == 1, proc.stderr
    proc, wall = freebody(site, "report", tmp_path / "out")
    assert proc.returncode == 0, proc.stderr
    assert "a plug-in, not imported by the report" in (tmp_path / "out" / "report.md").read_text()
    assert wall < STALL_S
