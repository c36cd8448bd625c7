"""Ctrl-C at any instant of a freebody command, start-up included (issue 28 item 7): exit 130, one
line on stderr, never a Python traceback.

Real processes and real signals.  The deterministic tests make an import of freebody's start-up
slow (a module named ``argparse`` on PYTHONPATH that sleeps, then loads the real one) and send
SIGINT while freebody is inside that import; the others send SIGINT at fixed instants after the
start of a short command, ``python -m freebody`` (where CPython turns a KeyboardInterrupt
raised inside an exec() into a death by SIGINT, rc -2, unless freebody exits itself).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CONSOLE_SCRIPT = Path(sys.executable).parent / "freebody"
SLOW_IMPORT_S = 2.0  # the sleep of the slowed import: long enough to be hit, short enough for the test
WAIT_S = 10.0  # at most this long for a process to reach its slow import, or to end after SIGINT
# after the start: imports, argument parsing, the command.  Not earlier: the first tens of ms are
# Python's own start-up (site), before any line of freebody runs (a SIGINT there is Python's).
INSTANTS_S = (0.25, 0.5, 0.65, 0.8, 1.4)
INTERRUPTED = 128 + signal.SIGINT

SLOW_ARGPARSE = f'''
import importlib.util, os, sys, sysconfig, time
open(os.environ["FREEBODY_TEST_MARKER"], "w").close()
time.sleep({SLOW_IMPORT_S})
spec = importlib.util.spec_from_file_location(
    "argparse", os.path.join(sysconfig.get_paths()["stdlib"], "argparse.py"))
module = importlib.util.module_from_spec(spec)
sys.modules["argparse"] = module
spec.loader.exec_module(module)
'''


def _env(tmp_path: Path, slow: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "FREEBODY_FAULT")}
    if slow:
        folder = tmp_path / "slow"
        folder.mkdir(exist_ok=True)
        (folder / "argparse.py").write_text(SLOW_ARGPARSE)
        env["PYTHONPATH"] = str(folder)
        env["FREEBODY_TEST_MARKER"] = str(tmp_path / "importing")
    return env


def _sigint_as_at_a_terminal() -> None:
    """In the child before exec: SIGINT at its default, as under a terminal.  A shell without job
    control starts background commands with SIGINT ignored (``cmd &``, e.g. a CI script run in the
    background), the child inherits that and Python keeps it ignored: then no Ctrl-C reaches it."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=WAIT_S)
    return proc.returncode, err


def _check_interrupted(rc: int, err: str) -> None:
    assert rc == INTERRUPTED, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert err.strip().splitlines() == ["freebody: interrupted"], err


@pytest.mark.parametrize("how", ["module", "console script"])
def test_ctrl_c_while_freebody_imports(tmp_path, how):
    """SIGINT inside an import of freebody's start-up (before any handler of freebody's main)."""
    if how == "console script" and not CONSOLE_SCRIPT.exists():
        pytest.skip(f"no console script at {CONSOLE_SCRIPT} (freebody not installed with pip)")
    command = ([sys.executable, "-m", "freebody"] if how == "module" else [str(CONSOLE_SCRIPT)])
    proc = subprocess.Popen([*command, "list"], cwd=tmp_path, env=_env(tmp_path, slow=True),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_sigint_as_at_a_terminal)
    deadline = time.monotonic() + WAIT_S
    while not (tmp_path / "importing").exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "freebody never reached its slowed import"
        time.sleep(0.01)
    _check_interrupted(*_interrupt(proc))


@pytest.mark.parametrize("delay", INSTANTS_S)
def test_ctrl_c_at_any_instant(tmp_path, delay):
    """SIGINT at fixed instants of a real short command (a run of one tiny case): 130 and one line,
    or, if the command had already finished, its own exit code and no traceback."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "freebody", "run", str(REPO / "cases" / "dzhanibekov.toml"),
                             "--engine", "reference", "--integrator", "rk4", "--dt", "0.01", "--quiet",
                             "--out", str(out)],
                            cwd=tmp_path, env=_env(tmp_path, slow=False),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_sigint_as_at_a_terminal)
    time.sleep(delay)
    if proc.poll() is not None:  # finished before the signal: nothing to interrupt
        _, err = proc.communicate()
        assert "Traceback" not in err, err
        return
    rc, err = _interrupt(proc)
    assert rc == INTERRUPTED, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("freebody: interrupted"), err
