"""The case's loads as a schedule of step segments, built once per run and shared by every adapter.

A :class:`~freebody.reference_impl.problem.Load` acts on the steps k0 <= k < k1 (``Load.step_range``);
between two switch steps the set of active loads is constant.  :class:`LoadSchedule` cuts the
steps k >= 0 into :class:`Segment` s at those switches and pre-sums, per segment, what an engine
needs at each step:

- the parts that do not depend on the state: ``force`` (sum of every force, N, world) and
  ``torque`` (sum of the world couples, N m, world); ``constant`` = [force, torque] (6,);
- the parts whose torque about the COM depends on the state: forces at fixed world points,
  forces at body points, and the sum of the body-frame couples.

An engine that takes a world wrench about the COM writes ``constant`` plus the state-dependent
torque ``sum (p - x) x f + sum (R b) x f + R tau_b`` (see :meth:`Segment.wrench`); an engine that
takes forces at points and couples applies them as they are; one that wants the loads one by one
has ``Segment.loads``.  Sums are formed in the case's load order, starting from zeros, so every
adapter sees the same floating-point numbers.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

from freebody.reference_impl.problem import Load, Problem


@dataclass(frozen=True)
class Segment:
    """Steps k0 <= k < k1 (k1 may be ``inf``) with one set of active loads, pre-summed.

    loads : the active loads, in case order (empty: no load acts).
    constant : (6,) [sum of all forces (3,) N world, sum of world couples (3,) N m world].
    com_force : (3,) N world, the sum of the forces acting at the COM, or None when none does.
    point_forces : ((point (3,) m world, force (3,) N world), ...): forces at fixed world points.
    body_point_forces : ((body_point (3,) m body frame, force (3,) N world), ...).
    body_torque : (3,) N m body frame, the sum of the body-frame couples, or None when zero.
    """

    k0: int
    k1: float
    loads: tuple[Load, ...]
    constant: np.ndarray
    com_force: np.ndarray | None
    point_forces: tuple[tuple[np.ndarray, np.ndarray], ...]
    body_point_forces: tuple[tuple[np.ndarray, np.ndarray], ...]
    body_torque: np.ndarray | None

    @property
    def force(self) -> np.ndarray:
        """(3,) N world: the sum of every active force."""
        return self.constant[0:3]

    @property
    def torque(self) -> np.ndarray:
        """(3,) N m world: the sum of the world couples."""
        return self.constant[3:6]

    @property
    def active(self) -> bool:
        """Whether any load acts on these steps."""
        return bool(self.loads)

    @property
    def state_dependent(self) -> bool:
        """Whether the wrench about the COM depends on the state (point forces, body couples)."""
        return bool(self.point_forces or self.body_point_forces or self.body_torque is not None)

    def wrench(self, x: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(6,) [force (3,) N world, torque about the COM (3,) N m world] at COM position x (3,)
        m world and rotation R (3, 3) body -> world."""
        out = self.constant.copy()
        for point, f in self.point_forces:
            out[3:6] += np.cross(point - x, f)
        for body_point, f in self.body_point_forces:
            out[3:6] += np.cross(R @ body_point, f)
        if self.body_torque is not None:
            out[3:6] += R @ self.body_torque
        return out


def _segment(k0: int, k1: float, loads: tuple[Load, ...]) -> Segment:
    constant = np.zeros(6)
    body_torque = np.zeros(3)
    com = np.zeros(3)
    has_com = False
    for ld in loads:
        constant[0:3] += ld.force
        constant[3:6] += ld.torque
        body_torque += ld.body_torque
        if ld.point is None and ld.body_point is None and np.any(ld.force != 0.0):
            com = com + ld.force
            has_com = True
    point = tuple((np.array(ld.point), np.array(ld.force)) for ld in loads
                  if ld.point is not None)
    body_point = tuple((np.array(ld.body_point), np.array(ld.force)) for ld in loads
                       if ld.point is None and ld.body_point is not None)
    for a in (constant, body_torque, com):
        a.setflags(write=False)
    return Segment(k0, k1, tuple(loads), constant, com if has_com else None, point, body_point,
                   body_torque if np.any(body_torque) else None)


class LoadSchedule:
    """A problem's loads at time step dt as segments covering every step k >= 0, ascending."""

    def __init__(self, problem: Problem, dt: float):
        edges = sorted({0} | {int(k) for ld in problem.loads for k in ld.step_range(dt)
                              if np.isfinite(k) and k > 0})
        self.segments: tuple[Segment, ...] = tuple(
            _segment(k0, edges[i + 1] if i + 1 < len(edges) else np.inf,
                     problem.active_loads(k0, dt))
            for i, k0 in enumerate(edges))
        self._starts = [s.k0 for s in self.segments]

    def at(self, k: int) -> Segment:
        """The segment holding step k (k >= 0)."""
        return self.segments[bisect.bisect_right(self._starts, k) - 1]

    def stretches(self, k_start: int, k_end: int):
        """(segment, ka, kb) for the steps k_start <= k < k_end cut where the active loads change."""
        for seg in self.segments:
            ka, kb = max(seg.k0, k_start), min(seg.k1, k_end)
            if ka < kb:
                yield seg, int(ka), int(kb)

    @property
    def empty(self) -> bool:
        """Whether no load ever acts."""
        return not any(s.active for s in self.segments)
