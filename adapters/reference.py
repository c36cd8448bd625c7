"""The reference integrators of ``reference_impl`` wrapped as an engine, so the harness treats
every engine alike.

Conventions: canonical throughout (no conversion).  Integrators: every name in
``reference_impl.integrators.INTEGRATORS``; an old name (``INTEGRATOR_ALIASES``, e.g.
``symplectic-euler``, now ``lie-euler``) is taken for the current one (:attr:`integrator_aliases`:
``--integrator`` resolves it in :func:`freebody.run.matrix.select_integrators`, and the adapter
itself accepts it), but never offered.  Always available (numpy and numba, both required
dependencies of freebody).  The maps are the compiled step functions of
``reference_impl.compiled`` (those ``integrators.simulate`` runs), stepped from the adapter's own
state: :meth:`advance` continues from where the previous call ended (step index ``k``, the
integrated state kept as the scheme holds it, e.g. R and L for a matrix scheme), so a long run can
be delivered in chunks (:meth:`Adapter.chunks`) with memory bounded by the chunk.  The pieces
together are ``integrators.simulate``'s trajectory bit for bit (the same step functions, called
with the same step indices on the same floats: ``tests/test_chunked_judging.py``).
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np

from freebody import __version__ as _freebody_version
from freebody.reference_impl import compiled as _c
from freebody.reference_impl.conventions import Trajectory
from freebody.reference_impl.integrators import (INTEGRATOR_ALIASES, INTEGRATORS, canonical_integrator,
                                                 initial_arrays, simulate)
from .base import Adapter, LOAD_SAMPLING_PER_STAGE

# euler-quat, lie-euler, rk4, implicit-midpoint, rkmk4: on (x, q, p, L) with I_b^-1
_QUAT_SCHEMES = _c.QUAT_SCHEMES
# the maps stepped from the adapter's state (the others: integrated whole, handed out in pieces)
CONTINUED = ("euler-matrix", "euler-matrix-gs", "semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro",
             *_QUAT_SCHEMES)


@_c.jit
def _continue_matrix(k0, x, R, p, L, dt, steps, M, I_inv, Mg, loads, gram, out_x, out_q, out_v, out_w,
                     out_ortho):
    """Rows 1..steps after the state (x, R, p, L) of step k0 (as compiled.run_euler_matrix writes
    them); returns the state after the last step."""
    for i in range(steps):
        x, R, p, L = _c.euler_matrix_step(k0 + i, x, R, p, L, dt, M, I_inv, Mg, loads, gram)
        q, w, ortho = _c.matrix_outputs(R, L, I_inv)
        _c.put_row(out_x, i + 1, x)
        _c.put_row(out_q, i + 1, q)
        _c.put_row(out_v, i + 1, _c.div(p, M))
        _c.put_row(out_w, i + 1, w)
        out_ortho[i + 1] = ortho
    return x, R, p, L


@_c.jit
def _continue_quat(scheme, k0, x, q, p, L, dt, steps, M, I_inv, g, loads, out_x, out_q, out_v, out_w):
    """Rows 1..steps after the state (x, q, p, L) of step k0 (as compiled.run_quat)."""
    for i in range(steps):
        if scheme == _c.EULER_QUAT:
            x, q, p, L = _c.euler_quat_step(k0 + i, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == _c.LIE_EULER:
            x, q, p, L = _c.lie_euler_step(k0 + i, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == _c.IMPLICIT_MIDPOINT:
            x, q, p, L = _c.implicit_midpoint_step(k0 + i, x, q, p, L, dt, M, I_inv, g, loads)
        elif scheme == _c.RKMK4:
            x, q, p, L = _c.rkmk4_step(k0 + i, x, q, p, L, dt, M, I_inv, g, loads)
        else:
            x, q, p, L = _c.rk4_step(k0 + i, x, q, p, L, dt, M, I_inv, g, loads)
        _c.put_row(out_x, i + 1, x)
        _c.put_row(out_q, i + 1, q)
        _c.put_row(out_v, i + 1, _c.div(p, M))
        _c.put_row(out_w, i + 1, _c.omega_world(_c.matrix_from_quat(q), I_inv, L))
    return x, q, p, L


@_c.jit
def _continue_semi_implicit(k0, x, q, v, w_b, dt, steps, M, I_b, I_inv, g, loads, implicit_gyro,
                            out_x, out_q, out_v, out_w):
    """Rows 1..steps after the state (x, q, v, w_b) of step k0 (as compiled.run_semi_implicit)."""
    for i in range(steps):
        x, q, v, w_b = _c.semi_implicit_step(k0 + i, x, q, v, w_b, dt, M, I_b, I_inv, g, loads, implicit_gyro)
        _c.put_row(out_x, i + 1, x)
        _c.put_row(out_q, i + 1, q)
        _c.put_row(out_v, i + 1, v)
        _c.put_row(out_w, i + 1, _c.matvec(_c.matrix_from_quat(q), w_b))
    return x, q, v, w_b


if hasattr(_c, "splitting_step"):
    @_c.jit
    def _continue_splitting(k0, x, q, p, L, dt, steps, M, axes, moments, I_inv, g, loads, out_x, out_q, out_v,
                            out_w):
        """Rows 1..steps after the state (x, q, p, L) of step k0 (as compiled.run_splitting)."""
        for i in range(steps):
            x, q, p, L = _c.splitting_step(k0 + i, x, q, p, L, dt, M, axes, moments, g, loads)
            _c.put_row(out_x, i + 1, x)
            _c.put_row(out_q, i + 1, q)
            _c.put_row(out_v, i + 1, _c.div(p, M))
            _c.put_row(out_w, i + 1, _c.omega_world(_c.matrix_from_quat(q), I_inv, L))
        return x, q, p, L

    CONTINUED = (*CONTINUED, "symplectic-splitting")


class ReferenceAdapter(Adapter):
    name: ClassVar[str] = "reference"
    import_name: ClassVar[str] = "numpy"
    integrators: ClassVar[tuple[str, ...]] = tuple(INTEGRATORS)
    # old name -> current name, accepted and not offered (``--integrator symplectic-euler``; the
    # base constructor takes an old name for its current one)
    integrator_aliases: ClassVar[dict[str, str]] = INTEGRATOR_ALIASES
    load_sampling: ClassVar[str] = LOAD_SAMPLING_PER_STAGE
    load_sampling_note: ClassVar[str] = ("every stage of rk4 / rkmk4 evaluates the loads at its own state; one-"
                                         "stage schemes at the step's start")
    conventions: ClassVar[dict[str, str]] = {
        "quaternion order": "(w, x, y, z), Hamilton, body -> world (canonical)",
        "angular velocity frame": "world",
        "inertia input": "full 3x3 tensor, body frame",
        "velocity clamp": "none",
        "damping": "none",
        "sleeping": "none",
    }

    @classmethod
    def engine_version(cls) -> str:
        return _freebody_version

    @classmethod
    def selfcheck_integrators(cls) -> tuple[str, ...]:
        # the self-checks' expectations are those of the engines' maps
        return tuple(i for i in cls.integrators if i.startswith("semi-implicit"))

    def build(self) -> None:
        """The initial state as ``compiled.simulate_compiled`` forms it (its row 0 and the
        scheme's integrated variables).  A map without a continuing driver here (one added to
        ``INTEGRATORS`` since) is integrated whole in :meth:`prepare` and handed out in pieces."""
        self._trajectory: Trajectory | None = None
        self._stepped = self.integrator in CONTINUED
        if not self._stepped:
            return
        M, I_b, I_inv, x, q, R, p, L, v, w = initial_arrays(self.problem)
        self._M, self._I_b, self._I_inv = float(M), _c.mat(I_b), _c.mat(I_inv)
        self._g = _c.vec(self.problem.gravity)
        self._Mg = _c.vec(M * np.asarray(self.problem.gravity, dtype=float))
        self._loads = _c.loads_of(self.problem, self.dt)
        if self.integrator in ("euler-matrix", "euler-matrix-gs"):
            self._state = (_c.vec(x), _c.mat(R), _c.vec(p), _c.vec(L))
        elif self.integrator.startswith("semi-implicit-"):
            self._state = (_c.vec(x), _c.vec(q), _c.vec(v), _c.vec(R.T @ w))
        else:
            self._state = (_c.vec(x), _c.vec(q), _c.vec(p), _c.vec(L))
        if self.integrator == "symplectic-splitting":
            from freebody.reference_impl.splitting import principal_frame

            frame = principal_frame(I_b)
            self._frame = (_c.mat(frame.axes), _c.vec(frame.moments))
        self._last = _c.simulate_compiled(self.problem, self.integrator, self.dt, 0)  # row 0

    def prepare(self, steps: int) -> None:
        if not self._stepped:
            self._integrate(self.k + steps)

    def _integrate(self, total: int) -> None:
        if self._trajectory is None or len(self._trajectory) <= total:
            self._trajectory = simulate(self.problem, self.integrator, self.dt, total)

    def advance(self, steps: int) -> Trajectory:
        steps = int(steps)
        if not self._stepped:
            k0 = self.k
            self._integrate(k0 + steps)
            tr = self._trajectory
            self.k = k0 + steps
            if k0 == 0 and len(tr) == steps + 1:
                return tr
            return tr.tail(k0).head(steps + 1)
        matrix = self._last.orthonormality_error is not None
        out = Trajectory.empty(steps + 1, with_orthonormality=matrix)
        for f in ("position", "quaternion_wxyz", "linear_velocity", "angular_velocity",
                  *(("orthonormality_error",) if matrix else ())):
            getattr(out, f)[0] = getattr(self._last, f)[0]
        k0, dt, M = self.k, self.dt, self._M
        rows = (out.position, out.quaternion_wxyz, out.linear_velocity, out.angular_velocity)
        if steps:
            if matrix:
                self._state = _continue_matrix(k0, *self._state, dt, steps, M, self._I_inv, self._Mg,
                                               self._loads, self.integrator == "euler-matrix-gs", *rows,
                                               out.orthonormality_error)
            elif self.integrator.startswith("semi-implicit-"):
                self._state = _continue_semi_implicit(k0, *self._state, dt, steps, M, self._I_b, self._I_inv,
                                                      self._g, self._loads,
                                                      self.integrator == "semi-implicit-implicit-gyro", *rows)
            elif self.integrator == "symplectic-splitting":
                self._state = _continue_splitting(k0, *self._state, dt, steps, M, *self._frame, self._I_inv,
                                                  self._g, self._loads, *rows)
            else:
                self._state = _continue_quat(_QUAT_SCHEMES[self.integrator], k0, *self._state, dt, steps, M,
                                             self._I_inv, self._g, self._loads, *rows)
        out.t[:] = (k0 + np.arange(steps + 1)) * dt
        self.k = k0 + steps
        self._last = out.take(np.array([steps]))  # a copy: the piece is the caller's
        return out


def map_orientations(problem, integrator: str, dt: float, steps: int, chunk_steps: int | None,
                     load_sampling: str = "per-stage"):
    """A reference map's orientations q (wxyz) in the pieces of ``Adapter.chunks(steps,
    chunk_steps)`` (any name ``integrators.simulate`` takes): stepped chunk by chunk where the
    adapter continues the map, else integrated whole and cut (``load_sampling``: the variant of a
    multi-stage engine map, see ``integrators.simulate``).  Only q is kept between pieces
    (scheme identification of a long run holds a few dozen of these streams at once)."""
    from freebody.reference_impl.truth import piece_bounds

    bounds = piece_bounds(steps, chunk_steps)
    integrator = canonical_integrator(integrator)
    if integrator in CONTINUED:
        adapter = ReferenceAdapter(problem, dt, integrator)
        for k0, k1 in bounds:
            yield adapter.advance(k1 - k0).quaternion_wxyz[0 if k0 == 0 else 1:]
        return
    q = simulate(problem, integrator, dt, steps, load_sampling=load_sampling).quaternion_wxyz
    for k0, k1 in bounds:
        yield q[0 if k0 == 0 else k0 + 1:k1 + 1]
