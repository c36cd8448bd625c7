"""Runs of the compiled maps from a start prepared once: what scheme identification needs many of.

:func:`integrators.simulate(problem, name, dt, steps) <freebody.reference_impl.integrators.simulate>`
forms a run's arguments from the case each time (its initial state normalised, rotated and
converted to the tuples the compiled code takes, its loads cut into segments, a whole Trajectory
allocated and filled with NaN): 30-250 us of Python against 3-10 us of arithmetic for a 10-step run.
Identification runs every candidate map from the case's start and from four perturbed starts, 135
runs for each (case, dt, steps, precision) of a suite.  Here a :class:`MapStart` holds what every
map's run takes from one start at one dt, formed once; :func:`run_map` then only forms the
map's own few arguments (a principal frame, a rotated angular velocity), allocates its output
rows and calls the same compiled driver (:mod:`compiled`, :mod:`compiled_engine_maps`) with the
same arguments, of the same types, as :func:`integrators.simulate`: the same trajectory bit for
bit, no new compiled signature (``tests/test_prepared_maps.py`` checks both, for every map).
:func:`map_orientations` keeps only a run's orientations (the other rows go to scratch arrays).

Numba is imported on the first run, not on import of this module (as :mod:`integrators` does).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .conventions import Trajectory
from .engine_maps import (DRAKE_SEMI_IMPLICIT, DRAKE_TABLEAUS, ENGINE_MAPS, NEWTON_STEPS, dart_exp_map_rot,
                          dart_log_map, initial_as_given, physx_principal_frame)
from .engine_maps import principal_frame as bullet_principal_frame
from .integrators import INTEGRATORS, canonical_integrator, initial_arrays
from .problem import Problem
from .rotations import matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply
from .sampling import LOAD_SAMPLING_PER_STAGE, check_load_sampling
from .splitting import principal_frame as splitting_principal_frame

__all__ = ["MapStart", "map_start", "run_map", "map_orientations", "frame_of"]

MATRIX_INTEGRATORS = ("euler-matrix", "euler-matrix-gs")  # run_euler_matrix: R as a matrix, its orthonormality
RK4_BODY_MAPS = ("rkmk4-body", "rk4-body-exp")  # MuJoCo's RK4 (run_mujoco_rk4), Munthe-Kaas first
NEWTON_KINDS = {name: i for i, name in enumerate(NEWTON_STEPS)}  # run_newton's switch, in its order


@dataclass(frozen=True)
class MapStart:
    """One start of a case at one time step, as every map's run takes it (formed once).

    problem : the case (its start: the case's own or a perturbed copy).  dt : s.
    loads : the loads at dt as the compiled maps take them (:class:`compiled.Loads`); the same
        for every start of a case (a perturbed start perturbs the state and the inertia, not the loads).
    ref : :func:`integrators.initial_arrays` (M, I_b, I_inv, x0, q0 normalised, R0, p0, L0, v0, w0),
        the reference integrators' start.
    given : :func:`engine_maps.initial_as_given` (M, I_b, I_inv, x0, q0 as written, v0, w0, g), the
        engine maps' start.
    The arrays' shapes, frames and units are those functions' (x m world, q (4,) wxyz body ->
    world, v m/s world, w rad/s world, L kg m^2/s world, I_b kg m^2 body frame, g m/s^2 world).
    """

    problem: Problem
    dt: float
    loads: tuple
    ref: tuple
    given: tuple

    @functools.cached_property
    def ref_tuples(self) -> tuple:
        """(x, q, p, L, I_inv, g) of :attr:`ref` as the compiled maps' tuples (``compiled.vec``/``mat``)."""
        from .compiled import mat, vec

        M, I_b, I_inv, x, q, R, p, L, v, w = self.ref
        return vec(x), vec(q), vec(p), vec(L), mat(I_inv), vec(self.problem.gravity)

    @functools.cached_property
    def given_tuples(self) -> tuple:
        """(x, q, v, w, I_b, I_inv, g) of :attr:`given` as the compiled maps' tuples."""
        from .compiled import mat, vec

        M, I_b, I_inv, x, q, v, w, g = self.given
        return vec(x), vec(q), vec(v), vec(w), mat(I_b), mat(I_inv), vec(g)

    @functools.cached_property
    def given_w_body(self) -> tuple:
        """R(q0)^T w0 of :attr:`given` as a tuple: the body-frame angular velocity (rad/s) the maps
        that carry it start from (MuJoCo's RK4, Brax's generalized)."""
        from .compiled import vec

        M, I_b, I_inv, x, q, v, w, g = self.given
        return vec(matrix_from_quat(q).T @ w)


def map_start(problem: Problem, dt: float, loads: tuple | None = None) -> MapStart:
    """The :class:`MapStart` of ``problem`` at ``dt``; ``loads``: its :func:`compiled.loads_of` at dt,
    if formed already (for another start of the same case: the same loads)."""
    from .compiled import loads_of

    return MapStart(problem, float(dt), loads_of(problem, dt) if loads is None else loads,
                    initial_arrays(problem), initial_as_given(problem))


def run_map(start: MapStart, name: str, steps: int, load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> Trajectory:
    """``integrators.simulate(start.problem, name, start.dt, steps, load_sampling=load_sampling)``
    from the prepared start: the same Trajectory (steps + 1 samples) bit for bit."""
    name = canonical_integrator(name)
    out = Trajectory.empty(int(steps) + 1, with_orthonormality=name in MATRIX_INTEGRATORS)
    _run(start, name, int(steps), load_sampling, _rows(out), out.orthonormality_error)
    out.t[:] = np.arange(int(steps) + 1) * start.dt
    return out


def map_orientations(start: MapStart, name: str, steps: int,
                     load_sampling: str = LOAD_SAMPLING_PER_STAGE) -> np.ndarray:
    """The orientations q (steps + 1, 4), wxyz body -> world, of :func:`run_map` (NaN until written,
    as there): all a map's run gives scheme identification.  The run's other rows go to scratch
    arrays (uninitialised: written by the run, never read)."""
    name, n = canonical_integrator(name), int(steps) + 1
    q = np.empty((n, 4))
    q.fill(np.nan)
    _run(start, name, n - 1, load_sampling, (np.empty((n, 3)), q, np.empty((n, 3)), np.empty((n, 3))),
         np.empty(n) if name in MATRIX_INTEGRATORS else None)
    return q


def _run(start: MapStart, name: str, steps: int, load_sampling: str, rows: tuple, ortho) -> None:
    """Run map ``name`` into ``rows`` (x, q, v, w: (steps + 1, 3), (steps + 1, 4), (steps + 1, 3) x 2,
    C-contiguous float64) and ``ortho`` ((steps + 1,), a matrix integrator's, else None)."""
    if name in INTEGRATORS:
        _run_reference(start, name, steps, rows, ortho)
    elif name in ENGINE_MAPS:
        per_stage = check_load_sampling(load_sampling) == LOAD_SAMPLING_PER_STAGE
        _run_engine_map(start, name, steps, per_stage, rows)
    else:
        raise KeyError(name)


def _rows(out: Trajectory) -> tuple:
    return out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity


def _compiled():
    """(:mod:`compiled`, :mod:`compiled_engine_maps`), imported on the first run (numba with them)."""
    global _COMPILED
    if _COMPILED is None:
        from . import compiled, compiled_engine_maps

        _COMPILED = compiled, compiled_engine_maps
    return _COMPILED


_COMPILED = None


def _run_reference(start: MapStart, name: str, steps: int, rows: tuple, ortho) -> None:
    """compiled.simulate_compiled's arguments and row 0, from the prepared start."""
    C = _compiled()[0]

    M, I_b, I_inv, x, q, R, p, L, v, w = start.ref
    tx, tq, tp, tL, tI_inv, tg = start.ref_tuples
    M, dt, loads = float(M), start.dt, start.loads
    out_x, out_q, out_v, out_w = rows
    if name in MATRIX_INTEGRATORS:
        C.run_euler_matrix(tx, C.mat(R), tp, tL, dt, steps, M, tI_inv, C.vec(M * start.problem.gravity),
                           loads, name == "euler-matrix-gs", *rows, ortho)
    elif name.startswith("semi-implicit-"):
        out_x[0], out_q[0], out_v[0], out_w[0] = x, q, v, w
        C.run_semi_implicit(tx, tq, C.vec(v), C.vec(R.T @ w), dt, steps, M, C.mat(I_b), tI_inv, tg, loads,
                            name == "semi-implicit-implicit-gyro", *rows)
    else:
        out_x[0], out_q[0], out_v[0] = x, q, p / M
        out_w[0] = np.array(start.problem.initial.angular_velocity, float)
        if name == "symplectic-splitting":
            frame = frame_of(splitting_principal_frame, I_b)
            C.run_splitting(tx, tq, tp, tL, dt, steps, M, C.mat(frame.axes), C.vec(frame.moments), tI_inv,
                            tg, loads, *rows)
        else:
            C.run_quat(C.QUAT_SCHEMES[name], tx, tq, tp, tL, dt, steps, M, tI_inv, tg, loads, *rows)


def _run_engine_map(start: MapStart, name: str, steps: int, per_stage: bool, rows: tuple) -> None:
    """compiled_engine_maps.simulate_compiled_engine_map's arguments and row 0, from the prepared start."""
    C, E = _compiled()
    mat, vec = C.mat, C.vec

    M, I_b, I_inv, x, q, v, w, g = start.given
    tx, tq, tv, tw, tI_b, tI_inv, tg = start.given_tuples
    dt, loads = start.dt, start.loads
    rows[0][0], rows[1][0], rows[2][0], rows[3][0] = x, q, v, w
    if name in RK4_BODY_MAPS:
        rkmk = name == "rkmk4-body"
        E.run_mujoco_rk4(tx, tq, tv, start.given_w_body, dt, steps, M, tI_b, tI_inv, tg, loads,
                         rkmk, rkmk, per_stage, *rows)
    elif name == "explicit-gyro-rescaled-momentum":
        moments, V, q_V = frame_of(physx_principal_frame, I_b)
        E.run_physx(tx, vec(quat_multiply(q, q_V)), tv, tw, dt, steps, M, vec(moments), mat(V.T),
                    vec(quat_conjugate(q_V)), tg, loads, *rows)
    elif name == DRAKE_SEMI_IMPLICIT or name in DRAKE_TABLEAUS:
        A, b = _drake_tableau(name)
        E.run_drake(np.concatenate([q, x, w, v]), dt, steps, M, tI_b, tg, loads, A, b,
                    name == DRAKE_SEMI_IMPLICIT, per_stage, *rows)
    elif name in NEWTON_KINDS:
        E.run_newton(NEWTON_KINDS[name], tx, tq, tv, tw, dt, steps, M, tI_b, tI_inv, tg, loads, *rows)
    elif name in E.BRAX_MAPS:
        kind = E.BRAX_MAPS.index(name)
        w0 = start.given_w_body if kind == 0 else tw  # generalized carries the body-frame w
        E.run_brax(tx, tq, tv, w0, dt, steps, M, tI_b, tI_inv, tg, loads, kind, *rows)
    elif name == "implicit-gyro-split-torque":
        moments, V, q_V = frame_of(bullet_principal_frame, I_b)
        B = E.bullet_matrix_from_quat(vec(quat_multiply(q, q_V)))
        E.run_bullet_maximal(tx, B, tv, tw, dt, steps, M, vec(moments), mat(V.T), vec(quat_conjugate(q_V)),
                             tg, loads, *rows)
    else:  # explicit-gyro-truncated-exp (DART)
        phi = dart_log_map(matrix_from_quat(q))
        rows[1][0] = quat_from_rotvec(phi)
        E.run_dart(tx, vec(phi), tv, vec(dart_exp_map_rot(phi).T @ w), dt, steps, M, tI_b, tI_inv, tg, loads,
                   *rows)


# principal frames found so far, by (function, I_body's bytes): a case's starts have a few inertias
# (its own and its perturbed starts'), each met again in every group (dt, steps) of the case
_FRAMES: dict = {}
FRAMES_KEPT = 1024  # at most this many (a sweep's bodies are each met once): then forgotten


def frame_of(frame, I_b: np.ndarray):
    """``frame(I_b)`` (a principal frame: splitting's, PyBullet's or PhysX's, arrays of kg m^2 and
    body-frame axes), computed once per inertia (the same function of the same floats: the same
    arrays), its arrays read-only."""
    key = (frame, np.asarray(I_b, dtype=float).tobytes())
    hit = _FRAMES.get(key)
    if hit is None:
        if len(_FRAMES) >= FRAMES_KEPT:
            _FRAMES.clear()
        hit = frame(I_b)
        for a in hit:
            if isinstance(a, np.ndarray):
                a.setflags(write=False)
        _FRAMES[key] = hit
    return hit


@functools.lru_cache(maxsize=None)
def _drake_tableau(name: str) -> tuple[np.ndarray, np.ndarray]:
    """compiled_engine_maps.drake_tableau_arrays(name), formed once per process (read only)."""
    from .compiled_engine_maps import drake_tableau_arrays

    return drake_tableau_arrays(name)
