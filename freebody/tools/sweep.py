"""Randomised sweeps: N physically valid random free bodies, run on every selected engine, reduced to
the distribution of each metric per engine and integrator, with the worst cases saved as case files.

A body of a sweep is drawn from ``np.random.default_rng(seed)`` in a fixed order, the same number of
draws per body, so the same seed always gives the same bodies and the first n bodies of a sweep of
N > n are those of the sweep of n.  Each body is:

- mass M, kg: log-uniform in [0.1, 10];
- principal moments built from the body's second moments of mass s_i = M l_i^2 (l_i, m, an rms
  half-extent, log-uniform in [0.02, 0.5]): I1 = s2 + s3, I2 = s1 + s3, I3 = s1 + s2, so the
  triangle inequality I_i + I_j >= I_k holds by construction (ratios up to about 300 : 1);
- a random principal frame Q (uniform on SO(3)): I_body = Q diag(I1, I2, I3) Q^T, full 3x3;
- a random orientation (uniform on SO(3)), position uniform in [-1, 1]^3 m, linear velocity
  N(0, 1) m/s per world axis;
- angular velocity, world frame: a uniform direction times a magnitude uniform in [0, max_spin] rad/s;
- gravity (0, 0, -9.81) m/s^2 on a coin flip ("mixed"), always ("on") or never ("off").

No loads act, so every body has the closed-form truth.  Each body exists first as case-file text
(:func:`dump_case`) and is parsed from that text, so the saved file of a worst case reproduces its
runs bit for bit: ``freebody run worst/<case>.toml --engine E --integrator I``.
"""
from __future__ import annotations

import json
import math
import re
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..input.casefile import parse_case
from ..reference_impl.problem import Body, InitialState, Problem
from ..reference_impl.rotations import matrix_from_quat, quat_normalize
from ..reference_impl.truth import truth_kind
from ..results.document import document_header
from ..results.io import read_json, write_json_atomic, write_text_atomic
from ..adapters.base import is_available, load_adapter
from ..adapters.capture import capture_output
from ..run import STATUSES, RunSpec, Simulated, Status, expand
from ..run.metrics import (ANGULAR_MOMENTUM_ERROR_MAX_REL, ENERGY_ERROR_MAX_REL, ORIENTATION_ERROR_MAX,
                           POSITION_ERROR_MAX, ROTATION_ORTHONORMALITY_ERROR_MAX)
from ..run.progress import ProgressDisplay
from ..report.summary import run_label

SWEEP_SCHEMA_VERSION = 2  # 2: "incomplete" (an interrupted sweep's finished runs); 1 reads as complete
READABLE_SWEEP_SCHEMAS = (1, 2)

# The metrics a sweep reduces (maxima over each run, see freebody.run.metrics), with a short label.
SWEEP_METRICS = {
    ORIENTATION_ERROR_MAX: "orientation error max (rad)",
    ANGULAR_MOMENTUM_ERROR_MAX_REL: "angular momentum error max (relative)",
    ENERGY_ERROR_MAX_REL: "energy error max (relative)",
    POSITION_ERROR_MAX: "COM position error max (m)",
    ROTATION_ORTHONORMALITY_ERROR_MAX: "||R^T R - 1||_F max (matrix integrators)",
}

GRAVITY = (0.0, 0.0, -9.81)  # m/s^2, world: the gravity a body gets when its coin says so
MASS_RANGE_KG = (0.1, 10.0)  # log-uniform
HALF_EXTENT_RANGE_M = (0.02, 0.5)  # log-uniform rms half-extent per principal axis
MAX_NON_OK_PER_GROUP = 3  # worst-case files kept for diverged/failed runs, per engine/integrator/dt


@dataclass(frozen=True)
class SweepSettings:
    """What a sweep draws and runs.

    seed : int >= 0, the seed of ``np.random.default_rng``.
    count : number of bodies, >= 1.
    duration : s, simulated time of every run.
    dts : time steps, s.
    max_spin : rad/s, bound on |w| at t = 0.
    gravity : "mixed" (a coin flip per body), "on" or "off".
    """

    seed: int
    count: int
    duration: float = 2.0
    dts: tuple[float, ...] = (0.01,)
    max_spin: float = 10.0
    gravity: str = "mixed"

    def as_dict(self) -> dict:
        return {"seed": self.seed, "count": self.count, "duration": self.duration,
                "dt": list(self.dts), "max_spin": self.max_spin, "gravity": self.gravity}


@dataclass(frozen=True)
class SweepBody:
    """One random body: the parsed problem, the case-file text it was parsed from, and the draws.

    params : principal_moments (3,) kg m^2 ascending, principal_frame_wxyz (4,), spin rad/s,
        gravity_on bool.
    """

    problem: Problem
    toml: str
    params: dict


# --- writing a case file ------------------------------------------------------------------------

def _f(x) -> str:
    """A float as TOML text that reads back as the same float (Python's shortest repr)."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"cannot write the non-finite number {x!r} to a case file")
    return repr(x)


def _vec(a) -> str:
    return "[" + ", ".join(_f(x) for x in np.asarray(a, dtype=float).reshape(-1)) + "]"


def _mat(a) -> str:
    return "[" + ", ".join(_vec(row) for row in np.asarray(a, dtype=float)) + "]"


_TOML_ESCAPED = re.compile(r'["\\\x00-\x1f\x7f]')  # quote, backslash, the control characters TOML forbids
_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\n": "\\n", "\t": "\\t"}


def _str(s: str) -> str:
    """A TOML basic string (escapes quote, backslash and the control characters TOML forbids)."""
    return '"' + _TOML_ESCAPED.sub(lambda m: _TOML_ESCAPES.get(m[0]) or f"\\u{ord(m[0]):04X}", s) + '"'


def dump_case(problem: Problem) -> str:
    """A case file (TOML text, the keys of :mod:`freebody.input.casefile`) that parses back to ``problem``.

    Floats are written with Python's shortest round-trip repr, the inertia as the full 3x3 tensor.
    Parsing renormalises the quaternion, which may move it by one rounding error; the sweep avoids
    even that by running the problem parsed from this very text.
    """
    pb, init = problem, problem.initial
    lines = [f"name = {_str(pb.name)}", f"description = {_str(pb.description)}"]
    if pb.duration_steps is not None:
        lines.append(f"duration_steps = {int(pb.duration_steps)}")
    else:
        lines.append(f"duration = {_f(pb.duration)}  # s")
    lines.append(f"dt = {_vec(pb.dts)}  # s")
    lines += ["", "[body]",
              f"mass = {_f(pb.body.mass)}  # kg",
              f"inertia = {_mat(pb.body.I_body)}  # kg m^2, about the COM, body frame",
              "", "[initial]",
              f"position = {_vec(init.position)}  # m, COM, world",
              f"orientation = {_vec(init.quaternion_wxyz)}  # (w, x, y, z), body -> world",
              f"linear_velocity = {_vec(init.linear_velocity)}  # m/s, COM, world",
              f"angular_velocity = {_vec(init.angular_velocity)}  # rad/s, world",
              "", "[world]",
              f"gravity = {_vec(pb.gravity)}  # m/s^2"]
    for ld in pb.loads:
        lines += ["", "[[loads]]"]
        has_torque = bool(np.any(ld.torque)) or bool(np.any(ld.body_torque))
        if np.any(ld.force) or ld.point is not None or ld.body_point is not None or not has_torque:
            lines.append(f"force = {_vec(ld.force)}  # N, world")
        if ld.point is not None:
            lines.append(f"point = {_vec(ld.point)}  # m, world point")
        if ld.body_point is not None:
            lines.append(f"body_point = {_vec(ld.body_point)}  # m, body frame")
        if np.any(ld.torque):
            lines.append(f"torque = {_vec(ld.torque)}  # N m, world frame")
        if np.any(ld.body_torque):
            lines.append(f"body_torque = {_vec(ld.body_torque)}  # N m, body frame")
        lines.append(f"start = {_f(ld.start)}  # s")
        if ld.steps is not None:
            lines.append(f"steps = {int(ld.steps)}")
        if ld.end is not None:
            lines.append(f"end = {_f(ld.end)}  # s")
    return "\n".join(lines) + "\n"


# --- drawing bodies -----------------------------------------------------------------------------

def _random_unit_quaternion(rng: np.random.Generator) -> np.ndarray:
    """Uniform on SO(3): a normalised 4D Gaussian, sign chosen with w >= 0.  Shape (4,), (w, x, y, z)."""
    q = quat_normalize(rng.normal(size=4))
    return -q if q[0] < 0 else q


def case_name(seed: int, index: int) -> str:
    return f"sweep_s{seed}_{index:04d}"


def random_body(rng: np.random.Generator, index: int, settings: SweepSettings) -> SweepBody:
    """Draw body ``index`` (the draws of earlier bodies must already have been taken from ``rng``)."""
    lo, hi = np.log10(MASS_RANGE_KG)
    mass = float(10.0 ** rng.uniform(lo, hi))
    lo, hi = np.log10(HALF_EXTENT_RANGE_M)
    s = mass * (10.0 ** rng.uniform(lo, hi, size=3)) ** 2  # kg m^2, second moments of mass
    moments = np.array([s[1] + s[2], s[0] + s[2], s[0] + s[1]])
    q_frame = _random_unit_quaternion(rng)
    Q = matrix_from_quat(q_frame)
    I = Q @ np.diag(moments) @ Q.T
    I = 0.5 * (I + I.T)  # exactly symmetric, so parsing (which symmetrises) keeps it bit for bit
    q0 = _random_unit_quaternion(rng)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    spin = float(settings.max_spin * rng.uniform(0.0, 1.0))
    w0 = spin * direction
    x0 = rng.uniform(-1.0, 1.0, size=3)
    v0 = rng.normal(0.0, 1.0, size=3)
    coin = bool(rng.uniform() < 0.5)  # always drawn, so the bodies do not depend on the mode
    gravity_on = {"mixed": coin, "on": True, "off": False}[settings.gravity]
    name = case_name(settings.seed, index)
    desc = (f"Random body {index} of 'freebody sweep --seed {settings.seed}': mass {mass:.4g} kg, "
            f"principal moments ({', '.join(f'{m:.4g}' for m in np.sort(moments))}) kg m^2 in a random "
            f"principal frame, |w| = {spin:.4g} rad/s, gravity {'on' if gravity_on else 'off'}; "
            f"closed-form truth.")
    draft = Problem(name=name, description=desc,
                    body=Body(mass=mass, I_body=I),
                    initial=InitialState(position=x0, quaternion_wxyz=q0, linear_velocity=v0,
                                         angular_velocity=w0),
                    gravity=np.array(GRAVITY if gravity_on else (0.0, 0.0, 0.0)),
                    duration=settings.duration, dts=settings.dts)
    text = dump_case(draft)
    problem = parse_case(tomllib.loads(text), f"<sweep body {name}>")
    params = {"principal_moments": np.sort(moments).tolist(), "principal_frame_wxyz": q_frame.tolist(),
              "spin": spin, "gravity_on": gravity_on, "truth": truth_kind(problem)}
    return SweepBody(problem, text, params)


def random_bodies(settings: SweepSettings) -> list[SweepBody]:
    """The sweep's ``count`` bodies, drawn from ``np.random.default_rng(seed)``."""
    rng = np.random.default_rng(settings.seed)
    return [random_body(rng, i, settings) for i in range(settings.count)]


def first_body_specs(settings: SweepSettings, engines: list[str], integrators: list[str] | None = None,
                     precisions: list[str] | None = None) -> list[RunSpec]:
    """The runs of the sweep's first body (every body has as many, with the same steps): what
    :mod:`freebody.run.budget` multiplies by ``count`` before anything is drawn."""
    body = random_body(np.random.default_rng(settings.seed), 0, settings)
    extra = {"precisions": precisions} if precisions else {}
    return expand([body.problem], engines, integrators, None, None, **extra)


# --- running ------------------------------------------------------------------------------------

def run_bodies(bodies: list[SweepBody], engines: list[str], integrators: list[str] | None = None,
               progress: bool = True, precisions: list[str] | None = None, *, jobs: int = 1,
               isolate: bool = True, on_interrupt: Callable[[list[dict]], str] | None = None,
               pool=None) -> list[dict]:
    """Run every body on every selected engine and integrator at the sweep's time steps.

    The runs go through :func:`freebody.run.suite.run_specs`, the executor of ``freebody run``:
    ``jobs`` isolated worker processes (``isolate=False``: this process, for debugging), the runs
    of one body at one dt sharing its truth and reference maps (:mod:`freebody.run.sharedcache`).
    Engines whose adapter steps many bodies at once (``supports_batch``; mjx: one
    ``jax.vmap``-ped batch per integrator, precision, dt and horizon) do so first, in this
    process; their runs are then judged in the workers like the others, so a batched run's result
    is that of the same run alone.  The numbers do not depend on ``jobs``.
    Returns the runs as results.json ``runs`` entries (in body, dt, engine, integrator order), without
    the per-run ``engine_settings`` (reproduce a run with ``freebody run`` to see them).
    On Ctrl-C, SIGTERM or SIGHUP the workers are ended, ``on_interrupt`` is called (signals held
    off) with the runs finished so far, in the same order, and says what it kept ("nothing
    written" without it); the interrupt is then re-raised.
    ``pool``: None, or the started :class:`~freebody.run.executor.LocalPool` to run them in
    (:func:`start_pool`; the caller closes it, this function only on an interrupt, before
    ``on_interrupt``).
    """
    from ..run import interrupts
    from ..run.suite import check_options, run_specs

    check_options(jobs, None, None, "local", None, isolate, engines)  # before any batch is stepped
    extra = {"precisions": precisions} if precisions else {}
    specs = expand([b.problem for b in bodies], engines, integrators, None, None, **extra)
    bar = ProgressDisplay(len(specs), "runs", enabled=progress, every=len(specs) // 10)
    counts = {s: 0 for s in STATUSES}
    finished: list = []

    def shown(out) -> None:
        r = out.result
        finished.append(out)
        counts[r.status] += 1
        bar.update(", ".join(f"{n} {s}" for s, n in counts.items() if n)
                   + f"  ({r.case} {r.engine}/{r.integrator})")

    try:
        with interrupts.signals_interrupt():  # SIGTERM, SIGHUP while the batches step, too
            batched = _batched_outputs(specs, progress)
            simulated = {i: batched[id(s)] for i, s in enumerate(specs) if id(s) in batched}
            _, outputs = run_specs(specs, None, engines, progress=False, on_result=shown, jobs=jobs,
                                   isolate=isolate, simulated=simulated, pool=pool)
    except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM, SIGHUP: the CLI exits with its code
        with interrupts.deferred():
            if pool is not None:  # the workers end before anything is written, as run_specs's do
                pool.close(kill=True)
            order = {s.key: i for i, s in enumerate(specs)}
            done = sorted(finished, key=lambda o: order.get(_key(o.result), len(specs)))
            kept = on_interrupt([_sweep_run(o) for o in done]) if on_interrupt and done else "nothing written"
            bar.note(f"{interrupts.describe(e)}: {bar.done} of {bar.total} runs finished; {kept}")
        raise
    return [_sweep_run(out) for out in outputs]


def _key(result) -> tuple:
    return result.key  # RunSpec.key's order (run.records.run_identity_key)


def _sweep_run(out) -> dict:
    """A finished run as a sweep.json ``runs`` entry (its results.json entry without
    ``engine_settings`` and ``trajectory``)."""
    run = out.result.to_json()
    run.pop("engine_settings", None)
    run.pop("trajectory", None)
    return run


def _batch_classes(engines, progress: bool) -> dict[str, type]:
    """engine -> its adapter class, for the installed engines whose adapter steps bodies as a
    batch (``supports_batch``).  An engine that is missing is left out, and so is one whose
    adapter fails to load: its runs go one by one and record their own skip or failure.  So does an
    engine that runs in an isolated environment (a version named on the command line): batches
    are stepped in this process, which holds another version of it.  The engine's cached facts
    (:mod:`freebody.envs.facts`) are asked first, so an engine that cannot batch is not imported
    here (MuJoCo's import, and the version probe of its GLFW, cost this process ~0.2 s CPU)."""
    from ..envs.engines import isolated
    from ..envs.facts import engine_facts

    out = {}
    for engine in dict.fromkeys(engines):
        try:
            if isolated(engine) or not is_available(engine):
                continue
            facts = engine_facts(engine)
            if facts is not None and not facts["supports_batch"]:
                continue
            with capture_output():  # some engines print a banner on import (pybullet)
                cls = load_adapter(engine)
            if cls.supports_batch:
                out[engine] = cls
        except Exception as e:
            if progress:
                sys.stderr.write(f"freebody: warning: the {engine} adapter failed to load "
                                 f"({type(e).__name__}: {e}); running its runs one by one\n")
    return out


def _batched_outputs(specs: list[RunSpec], progress: bool) -> dict[int, tuple[Simulated, str | None]]:
    """Step the runs of batch-capable engines (``supports_batch``) as one batch per (engine,
    integrator, precision, dt, steps) with the adapter class's ``simulate_batch``; id(spec) ->
    (its Simulated, the engine it ports).  A batch that cannot run leaves its runs to be stepped one
    by one."""
    classes = _batch_classes((s.engine for s in specs), progress)
    groups: dict[tuple, list[RunSpec]] = {}
    for s in specs:
        if s.engine in classes and s.integrator != "*":
            groups.setdefault((s.engine, s.integrator, s.precision, s.dt, s.steps), []).append(s)
    out: dict[int, tuple[Simulated, str | None]] = {}
    for (engine, integrator, precision, dt, steps), group in groups.items():
        cls = classes[engine]
        try:
            t0 = time.perf_counter()
            batch = cls.simulate_batch([s.problem for s in group], dt, steps, integrator, precision)
            wall = (time.perf_counter() - t0) / len(group)
        except Exception as e:  # the runs go one by one instead, and record their own failure
            if progress:
                sys.stderr.write(f"freebody: warning: batch of {len(group)} {engine}/{integrator}/{precision} "
                                 f"runs failed ({type(e).__name__}: {e}); running them one by one\n")
            continue
        version = cls.engine_version()
        settings = batch.engine_settings or [None] * len(group)
        for spec, tr, t_div, st in zip(group, batch.trajectories, batch.diverged_at_s, settings):
            reason = "state is not finite (NaN or inf)" if t_div is not None else ""
            if t_div is not None:  # keep the samples up to the blow-up, as a single run does
                tr = tr.head(int(np.searchsorted(tr.t, t_div, side="right")))
            out[id(spec)] = (Simulated(tr, t_div, reason, version, st, wall, batch.compile_time_s / len(group)),
                             cls.compare_with)
        if progress:
            sys.stderr.write(f"{engine}/{integrator}/{precision} dt={dt:g}: {len(group)} bodies in one batch "
                             f"(compile {batch.compile_time_s:.1f} s, step {batch.step_time_s:.2f} s)\n")
    return out


# --- reducing -----------------------------------------------------------------------------------

def group_label(run: dict) -> str:
    """engine/integrator[/precision] dt=<dt>: the unit over which a sweep's distributions are taken."""
    return f"{run_label(run)} dt={run['dt']:g}"


def summarize_runs(runs: list[dict]) -> dict:
    """Per engine/integrator/dt: status counts and, per metric, n, median, p95, worst, worst_case.

    Only finite values of ok runs enter a distribution (a diverged run has no meaningful maxima:
    it is counted in ``status``); a metric that no run defines (e.g. orthonormality for quaternion
    integrators) is omitted.
    """
    groups: dict[str, list[dict]] = {}
    for r in runs:
        groups.setdefault(group_label(r), []).append(r)
    out = {}
    for label, rs in groups.items():
        entry = {"engine": rs[0]["engine"], "integrator": rs[0]["integrator"], "dt": rs[0]["dt"],
                 "precision": rs[0].get("precision", "float64"),
                 "runs": len(rs), "status": {s: sum(r["status"] == s for r in rs) for s in STATUSES},
                 "metrics": {}}
        messages = sorted({r["message"] for r in rs
                           if r["status"] in (Status.SKIPPED, Status.FAILED) and r["message"]})
        if messages:
            entry["messages"] = messages[:3]
        for key in SWEEP_METRICS:
            pairs = [(r["metrics"].get(key), r["case"]) for r in rs if r["status"] == Status.OK]
            pairs = [(v, c) for v, c in pairs if v is not None]
            if not pairs:
                continue
            values = np.array([v for v, _ in pairs])
            worst = int(np.argmax(values))  # first of equal maxima: deterministic
            entry["metrics"][key] = {"n": len(values), "median": float(np.median(values)),
                                     "p95": float(np.percentile(values, 95)),
                                     "worst": float(values[worst]), "worst_case": pairs[worst][1]}
        out[label] = entry
    return out


def worst_cases(summary: dict, runs: list[dict]) -> list[dict]:
    """The runs worth a case file: per group, the worst body of each metric and up to
    MAX_NON_OK_PER_GROUP diverged or failed bodies.  Sorted by group, then kind."""
    out = []
    for label, entry in summary.items():
        base = {"group": label, "engine": entry["engine"], "integrator": entry["integrator"],
                "precision": entry["precision"], "dt": entry["dt"]}
        for key, stats in entry["metrics"].items():
            out.append({**base, "reason": key, "value": stats["worst"], "case": stats["worst_case"]})
        bad = [r for r in runs if group_label(r) == label and r["status"] in (Status.DIVERGED, Status.FAILED)]
        for r in bad[:MAX_NON_OK_PER_GROUP]:
            out.append({**base, "reason": r["status"], "value": r.get("diverged_at_s"), "case": r["case"],
                        "message": r["message"]})
    return out


def reproduce_command(worst: dict, path: str) -> str:
    precision = worst.get("precision", "float64")
    return (f"freebody run {path} --engine {worst['engine']} --integrator {worst['engine']}:"
            f"{worst['integrator']} --dt {worst['dt']:g}"
            + (f" --precision {precision}" if precision != "float64" else ""))


# --- the whole sweep ----------------------------------------------------------------------------

@dataclass(frozen=True)
class SweepOutcome:
    """A sweep's document (sweep.json), its report (sweep.txt) and wall time, s; ``worst_texts``:
    case name -> the case-file text of each worst case (worst/<name>.toml)."""

    document: dict
    report: str
    wall_time_s: float
    worst_texts: dict = field(default_factory=dict)


def sweep(settings: SweepSettings, engines: list[str], integrators: list[str] | None = None,
          out_dir: Path | None = None, progress: bool = True, precisions: list[str] | None = None,
          on_bodies: Callable[[list[SweepBody]], None] | None = None, *, jobs: int = 1,
          isolate: bool = True) -> SweepOutcome:
    """Draw the bodies, run them (``jobs`` worker processes, see :func:`run_bodies`), reduce; write
    sweep.json, sweep.txt and worst/*.toml to out_dir.  The documents do not depend on ``jobs``
    (apart from the wall times).

    Interrupted (Ctrl-C, SIGTERM, SIGHUP) with runs finished, the sweep of those runs (their
    bodies, ``"incomplete": true``) is written to ``out_dir/interrupted/`` and the interrupt
    re-raised: a complete sweep in out_dir is never touched by an interrupted one.  A complete
    sweep removes the interrupted one's files (those its sweep.json names, nothing else).
    The workers are started first (:func:`start_pool`): they import while the bodies are drawn."""
    t0 = time.perf_counter()
    pool = start_pool(settings, engines, integrators, precisions, jobs, isolate)
    try:
        return _sweep(settings, engines, integrators, out_dir, progress, precisions, on_bodies, jobs,
                      isolate, pool, t0)
    finally:
        if pool is not None:  # closed already unless the runs raised
            from ..run import interrupts

            with interrupts.deferred():  # a second Ctrl-C must not leave workers behind
                pool.close(kill=True)


def start_pool(settings: SweepSettings, engines: list[str], integrators: list[str] | None,
               precisions: list[str] | None, jobs: int, isolate: bool = True):
    """The :class:`~freebody.run.executor.LocalPool` of a sweep's runs (:func:`freebody.run.suite.local_pool`, the pool ``run_specs``
    would make: ``min(jobs, runs)`` workers, no time limit), its workers started now, before the
    bodies are drawn, so that their start-up overlaps this process's until the runs are sent;
    None when the runs go elsewhere (``isolate=False``; an engine in an environment of its own,
    whose workers ``run_specs`` picks by the runs)."""
    from ..envs.engines import interpreters
    from ..run.suite import check_options, local_pool

    check_options(jobs, None, None, "local", None, isolate, engines)  # bad input: no worker started
    runs = settings.count * len(first_body_specs(settings, engines, integrators, precisions))
    if not isolate or runs == 0 or interpreters(engines):
        return None
    pool = local_pool(jobs, runs, engines)
    pool.start(pool.jobs)
    return pool


def _sweep(settings, engines, integrators, out_dir, progress, precisions, on_bodies, jobs, isolate,
           pool, t0: float) -> SweepOutcome:
    """:func:`sweep` once its pool is started (``pool``, or None: run_specs's own)."""
    from ..run.suite import engine_versions

    bodies = random_bodies(settings)
    if on_bodies:
        on_bodies(bodies)

    def keep(runs: list[dict]) -> str:
        if out_dir is None:
            return "nothing written (no output folder)"
        folder = Path(out_dir) / INTERRUPTED
        _clear_interrupted(Path(out_dir))
        made = set(r["case"] for r in runs)
        _write(_outcome(settings, engines, [b for b in bodies if b.problem.name in made], runs,
                        time.perf_counter() - t0, engine_versions, folder, incomplete=True), folder)
        return f"kept in {folder / 'sweep.json'} (marked incomplete)"

    runs = run_bodies(bodies, engines, integrators, progress=progress, precisions=precisions, jobs=jobs,
                      isolate=isolate, on_interrupt=keep, pool=pool)
    if pool is not None:
        pool.close()  # the workers exit while the document is made and written
    outcome = _outcome(settings, engines, bodies, runs, time.perf_counter() - t0, engine_versions, out_dir)
    if out_dir is not None:
        _write(outcome, Path(out_dir))
        _clear_interrupted(Path(out_dir))
    return outcome


INTERRUPTED = "interrupted"  # the folder (in the output folder) of an interrupted sweep


def _outcome(settings: SweepSettings, engines: list[str], bodies: list[SweepBody], runs: list[dict],
             wall: float, versions, out_dir, incomplete: bool = False) -> SweepOutcome:
    """The sweep document of ``runs`` (of ``bodies``) and its report; the worst cases' texts in
    ``outcome.document`` are attached as ``_texts`` (popped by :func:`_write`)."""
    summary = summarize_runs(runs)
    worst = worst_cases(summary, runs)
    for w in worst:
        w["file"] = f"worst/{w['case']}.toml"
        w["command"] = reproduce_command(w, w["file"])  # relative to the sweep's directory
    doc = document_header(
        SWEEP_SCHEMA_VERSION, versions(engines),
        kind="freebody sweep",
        incomplete=incomplete,
        seed=settings.seed,
        count=settings.count,
        settings=settings.as_dict(),
        bodies=[_body_record(b) for b in bodies],
        runs=runs,
        summary=summary,
        worst_cases=worst,
        wall_time_s=wall,
    )
    report = format_report(doc, str(out_dir) if out_dir is not None else None)
    texts = {b.problem.name: b.toml for b in bodies}
    return SweepOutcome(doc, report, wall, {w["case"]: texts[w["case"]] for w in worst})


def _write(outcome: SweepOutcome, out_dir: Path) -> None:
    """worst/*.toml, then sweep.json and sweep.txt, each atomically."""
    for name in sorted(outcome.worst_texts):
        write_text_atomic(out_dir / "worst" / f"{name}.toml", outcome.worst_texts[name])
    write_json_atomic(out_dir / "sweep.json", outcome.document)
    write_text_atomic(out_dir / "sweep.txt", outcome.report + "\n")


def _clear_interrupted(out_dir: Path) -> None:
    """Remove the interrupted sweep in ``out_dir/interrupted/``: sweep.txt, the worst-case files
    its sweep.json names, sweep.json last, then the folders if that empties them.  Only if its
    sweep.json is an incomplete freebody sweep; a file of anyone else there is left alone."""
    folder = out_dir / INTERRUPTED
    try:
        doc = json.loads((folder / "sweep.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return
    if not (isinstance(doc, dict) and doc.get("kind") == "freebody sweep" and doc.get("incomplete") is True):
        return
    names = {c.get("file") for c in doc.get("worst_cases") or [] if isinstance(c, dict)}
    for name in sorted(n for n in names if isinstance(n, str) and _WORST_FILE.fullmatch(n)):
        _unlink(folder / name)
    _unlink(folder / "sweep.txt")
    _unlink(folder / "sweep.json")
    for empty in (folder / "worst", folder):
        try:
            empty.rmdir()
        except OSError:  # not empty (a user's file), or gone
            pass


_WORST_FILE = re.compile(r"worst/sweep_s\d+_\d+\.toml")  # the names freebody gives worst-case files


def _unlink(path: Path) -> None:
    try:
        if path.is_file() and not path.is_symlink():
            path.unlink()
    except OSError:
        pass


def _body_record(b: SweepBody) -> dict:
    pb = b.problem
    return {"case": pb.name, "mass": pb.body.mass, "inertia": pb.body.I_body.tolist(),
            "position": pb.initial.position.tolist(), "orientation": pb.initial.quaternion_wxyz.tolist(),
            "linear_velocity": pb.initial.linear_velocity.tolist(),
            "angular_velocity": pb.initial.angular_velocity.tolist(), "gravity": pb.gravity.tolist(),
            **b.params}


def _g(x) -> str:
    return "-" if x is None else f"{x:.2e}"


def format_report(doc: dict, out_dir: str | None) -> str:
    """The plain-text sweep report: status counts, one distribution table per metric, worst cases."""
    s = doc["settings"]
    runs = doc["runs"]
    counts = {st: sum(r["status"] == st for r in runs) for st in STATUSES}
    lines = [f"freebody sweep: seed {s['seed']}, {s['count']} random bodies, {s['duration']:g} s at "
             f"dt = {', '.join(f'{d:g}' for d in s['dt'])} s, |w| <= {s['max_spin']:g} rad/s, "
             f"gravity {s['gravity']}; closed-form truth",
             f"{len(runs)} runs: " + ", ".join(f"{n} {st}" for st, n in counts.items())
             + f" ({doc['wall_time_s']:.1f} s)"]
    if doc.get("incomplete"):
        lines.append(f"INCOMPLETE: interrupted; only the {len(runs)} finished runs, of {len(doc['bodies'])} of "
                     f"the {s['count']} bodies, are counted below")
    summary = doc["summary"]
    w = max([len(k) for k in summary] + [len("engine/integrator dt")])
    for key, title in SWEEP_METRICS.items():
        rows = [(label, e) for label, e in summary.items() if key in e["metrics"]]
        if not rows:
            continue
        lines += ["", title,
                  f"{'engine/integrator dt':<{w}}  {'ok/runs':>9}  {'median':>9}  {'p95':>9}  {'worst':>9}  worst case"]
        for label, e in rows:
            m = e["metrics"][key]
            lines.append(f"{label:<{w}}  {e['status'][Status.OK]:>4}/{e['runs']:<4}  {_g(m['median']):>9}  "
                         f"{_g(m['p95']):>9}  {_g(m['worst']):>9}  {m['worst_case']}")
    not_ok = [(label, e) for label, e in summary.items() if e["status"][Status.OK] < e["runs"]]
    if not_ok:
        lines += ["", "not ok:"]
        for label, e in not_ok:
            parts = ", ".join(f"{n} {st}" for st, n in e["status"].items() if n and st != Status.OK)
            bad = [c["case"] for c in doc["worst_cases"]
                   if c["group"] == label and c["reason"] in (Status.DIVERGED, Status.FAILED)]
            more = f" (e.g. {', '.join(bad)})" if bad else ""
            lines.append(f"  {label}: {parts}{more}")
            for msg in e.get("messages", []):
                lines.append(f"    {msg}")
    if doc["worst_cases"]:
        where = f"{out_dir}/worst/" if out_dir else "worst/"
        files = sorted({c["case"] for c in doc["worst_cases"]})
        example = doc["worst_cases"][0]
        lines += ["", f"worst cases: {len(files)} case files in {where} (which run each one is worst for: "
                      f"sweep.json worst_cases); reproduce one with e.g.",
                  "  " + reproduce_command(example, f"{where}{example['case']}.toml")]
    return "\n".join(lines)


def load_sweep(path: str | Path) -> dict:
    """Read a sweep.json (or a directory holding one), in the newest schema: a schema-1 document
    (before interrupted sweeps were kept) reads as complete (``"incomplete": false``)."""
    from ..errors import InputError

    p = Path(path)
    if p.is_dir():
        p = p / "sweep.json"
    doc = read_json(p, str(p))
    version = doc.get("schema_version") if isinstance(doc, dict) else None
    if version not in READABLE_SWEEP_SCHEMAS:
        raise InputError(f"{p}: schema_version: expected {SWEEP_SCHEMA_VERSION} (or an earlier one, "
                         f"{', '.join(map(str, READABLE_SWEEP_SCHEMAS[:-1]))}), got {version!r}; re-run "
                         f"freebody sweep with this version")
    doc = dict(doc)
    doc.setdefault("incomplete", False)  # schema 1
    if not isinstance(doc["incomplete"], bool):
        raise InputError(f"{p}: incomplete: must be true or false, got {doc['incomplete']!r}")
    doc["schema_version"] = SWEEP_SCHEMA_VERSION
    return doc
