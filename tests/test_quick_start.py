"""The README's test command is what CI runs: `.ci/run` must install the same extras and call
pytest with the same options as the quick start's second command (the guide's rule; a drift
here means CI tests something other than what the README promises)."""
from __future__ import annotations

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _readme_test_command() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = text[text.index("# 2. install the test dependencies"):]
    return block.splitlines()[1].strip()


def test_ci_installs_and_runs_what_the_readme_says():
    command = _readme_test_command()
    extras = re.search(r"pip install -q -e '(\.\[[^\]]+\])'", command).group(1)
    pytest_call = command[command.index(".venv/bin/python -m pytest"):]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert f"pip install -q -e '{extras}'" in ci, (extras, "not the extras .ci/run installs")
    assert re.search(rf"^{re.escape(pytest_call)}$", ci, re.M), (pytest_call, "not the pytest call of .ci/run")
