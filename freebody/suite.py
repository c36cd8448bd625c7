"""Execute a list of runs, show progress, write results.json and the trajectory files."""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable, TextIO

from .adapters.base import EngineMissing, load_adapter
from .results import results_document, save_trajectory, trajectory_filename, write_json_atomic
from .runner import RunOutput, RunSpec, TruthCache, execute


class Progress:
    """A one-line progress display on a terminal, one line per run otherwise (e.g. in CI logs)."""

    def __init__(self, total: int, stream: TextIO | None = None, enabled: bool = True):
        self.total = total
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = self.enabled and self.stream.isatty()
        self.done = 0
        self.t0 = time.perf_counter()

    def update(self, out: RunOutput) -> None:
        self.done += 1
        if not self.enabled:
            return
        r = out.result
        label = f"{r.case} {r.engine}/{r.integrator} dt={r.dt:g}"
        elapsed = time.perf_counter() - self.t0
        line = f"[{self.done}/{self.total}] {elapsed:6.1f}s {r.status:8s} {label}"
        if self.tty:
            self.stream.write("\r\033[K" + line[:150])
            if self.done == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def engine_versions(engines: list[str]) -> dict[str, str | None]:
    """Installed engine versions (None for an engine that is not installed or fails to import)."""
    out = {}
    for e in engines:
        try:
            out[e] = load_adapter(e).engine_version()
        except EngineMissing:
            out[e] = None
        except Exception:
            out[e] = None
    return out


def run_specs(specs: list[RunSpec], out_dir: Path | None, engines: list[str],
              progress: bool = True, save_every: int = 1,
              on_result: Callable[[RunOutput], None] | None = None) -> tuple[dict, list[RunOutput]]:
    """Execute every spec (serially, sharing truths), write results.json and trajectories to out_dir.

    On KeyboardInterrupt the finished runs are written with ``"incomplete": true`` and the
    interrupt is re-raised.
    """
    cache = TruthCache()
    bar = Progress(len(specs), enabled=progress)
    outputs: list[RunOutput] = []
    runs: list[dict] = []
    versions = engine_versions(engines)

    def write(incomplete: bool) -> dict:
        doc = results_document(runs, versions, incomplete=incomplete)
        if out_dir is not None:
            write_json_atomic(Path(out_dir) / "results.json", doc)
        return doc

    try:
        for spec in specs:
            out = execute(spec, cache)
            run = out.result.to_json()
            if out_dir is not None and out.trajectory is not None:
                rel = trajectory_filename(run)
                save_trajectory(Path(out_dir), rel, out.trajectory, out.truth, every=save_every)
                run["trajectory"] = rel
            runs.append(run)
            outputs.append(out)
            bar.update(out)
            if on_result:
                on_result(out)
    except KeyboardInterrupt:
        write(incomplete=True)
        raise
    return write(incomplete=False), outputs
