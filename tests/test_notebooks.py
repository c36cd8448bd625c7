"""The teaching notebooks (``examples/*.ipynb``, docs/teaching.md) run top to bottom in a fresh
kernel of this interpreter without an error, draw their figures and print their key results.

Each lesson checks its own numbers with ``assert`` lines (a fitted slope out of its range, a flip
at the wrong time, fails the notebook, and so this test); here we check that every code cell ran,
that no cell raised, and that the figures and the key lines are there.  The notebooks are stored
without outputs, so a diff shows only what a teacher would read.

nbclient, nbformat and ipykernel come with the ``test`` extra; without them these tests are skipped
with the reason.  The kernel is this interpreter (``sys.executable -m ipykernel_launcher``), from a
kernel spec written for the test, so no ``jupyter kernelspec install`` is needed and a user's own
``python3`` kernel, which may be another Python, is never used.
"""
from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("*.ipynb"))
LESSONS = ["01_integrators", "02_quiz", "03_dzhanibekov"]

# One cell on a loaded 2-core machine: the slowest takes about 5 s alone (lesson 3's 45 runs, or its
# GIF); a cell still running after this is stuck, not slow.
CELL_TIMEOUT_S = 300
# What each lesson must show: figures (inline PNGs and GIFs) at least, and lines of its printed text.
MIN_FIGURES = {"01_integrators": 3, "02_quiz": 1, "03_dzhanibekov": 4}
KEY_OUTPUT = {
    "01_integrators": ["fitted slope 1.27", "one-step error / h^2", "energy gained in one step",
                       "euler-matrix-gs on I = diag(1, 2, 2.5)"],
    "02_quiz": ["freebody euler-matrix", "closed forms hold", "|x - x_exact| at 0.2 s"],
    "03_dzhanibekov": ["exact flips at [2.633 7.899] s", "tumbles", "on time", "GIF: 960 x 540 px"],
}
MIN_ASSERT_LINES = 5  # every lesson checks its claims; fewer asserts than this means they were lost


def _nbformat():
    return pytest.importorskip("nbformat", reason="nbformat not installed (pip install -e '.[test]')")


def test_every_lesson_is_there_clean_and_self_checking():
    """The three lessons exist, are valid notebooks stored without outputs, and assert their numbers."""
    nbformat = _nbformat()
    assert [p.stem for p in NOTEBOOKS] == LESSONS
    for path in NOTEBOOKS:
        nb = nbformat.read(path, as_version=4)
        nbformat.validate(nb)
        code = [c for c in nb.cells if c.cell_type == "code"]
        assert all(not c.outputs and c.execution_count is None for c in code), f"{path.name} has outputs"
        asserts = sum(len(re.findall(r"^\s*assert ", c.source, flags=re.M)) for c in code)
        assert asserts >= MIN_ASSERT_LINES, (path.name, asserts)
        assert nb.metadata["kernelspec"]["language"] == "python"


@pytest.fixture(scope="module")
def kernel_dirs(tmp_path_factory):
    """A kernel spec that starts this interpreter's ipykernel (a folder for KernelSpecManager)."""
    pytest.importorskip("ipykernel", reason="ipykernel not installed (pip install -e '.[test]')")
    root = tmp_path_factory.mktemp("kernels")
    spec = root / "freebody-test"
    spec.mkdir()
    spec.joinpath("kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "freebody test kernel", "language": "python"}))
    return [str(root)]


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, kernel_dirs, record_property):
    nbformat = _nbformat()
    nbclient = pytest.importorskip("nbclient", reason="nbclient not installed (pip install -e '.[test]')")
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    nb = nbformat.read(path, as_version=4)
    km = KernelManager(kernel_name="freebody-test",
                       kernel_spec_manager=KernelSpecManager(kernel_dirs=kernel_dirs, ensure_native_kernel=False))
    client = nbclient.NotebookClient(nb, km=km, timeout=CELL_TIMEOUT_S,
                                     resources={"metadata": {"path": str(EXAMPLES)}})
    start = time.perf_counter()
    client.execute()  # raises CellExecutionError, with the cell and its traceback, when a cell fails
    record_property("seconds", round(time.perf_counter() - start, 1))

    code = [c for c in nb.cells if c.cell_type == "code"]
    assert all(c.execution_count for c in code)
    outputs = [o for c in code for o in c.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    figures = [o for o in outputs if o.output_type == "display_data"
               and ({"image/png", "image/gif"} & set(o.get("data", {})))]
    assert len(figures) >= MIN_FIGURES[path.stem], len(figures)
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    for line in KEY_OUTPUT[path.stem]:
        assert line in text, line
