"""Metrics of a run against its truth, and the one place that decides a run's divergence.

All series are arrays of shape (N,) over the samples t_k; maxima and finals are floats or None
(None where a value is undefined, e.g. a relative error whose scale is zero).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..reference_impl.conventions import Trajectory, angular_momentum, kinetic_energy, potential_energy
from ..reference_impl.problem import Problem
from ..reference_impl.rotations import geodesic_angle
from .. import tolerances as tol
from ..numbers import finite_or_none

# The keys of a results.json ``metrics`` dict, defined once (they are the schema: every module
# names a metric through these constants).
ORIENTATION_ERROR_MAX = "orientation_error_max_rad"
ORIENTATION_ERROR_FINAL = "orientation_error_final_rad"
ANGULAR_MOMENTUM_ERROR_MAX_REL = "angular_momentum_error_max_rel"
ENERGY_ERROR_MAX_REL = "energy_error_max_rel"
POSITION_ERROR_MAX = "position_error_max_m"
ROTATION_ORTHONORMALITY_ERROR_MAX = "rotation_orthonormality_error_max"
ANGULAR_MOMENTUM_ERROR_MAX_ABS = "angular_momentum_error_max_abs"  # instead of _rel when the truth's L is 0
ENERGY_ERROR_MAX_ABS = "energy_error_max_abs_J"  # instead of _rel when the truth's KE is 0
# diverged runs: the orientation error over the samples before the divergence
ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE = "orientation_error_max_before_divergence_rad"

METRIC_KEYS = (  # the keys every judged run's metrics have
    ORIENTATION_ERROR_MAX,
    ORIENTATION_ERROR_FINAL,
    ANGULAR_MOMENTUM_ERROR_MAX_REL,
    ENERGY_ERROR_MAX_REL,
    POSITION_ERROR_MAX,
    ROTATION_ORTHONORMALITY_ERROR_MAX,
)
METRIC_NAMES = METRIC_KEYS + (  # every metric a run may have
    ANGULAR_MOMENTUM_ERROR_MAX_ABS,
    ENERGY_ERROR_MAX_ABS,
    ORIENTATION_ERROR_MAX_BEFORE_DIVERGENCE,
)


@dataclass(frozen=True)
class Series:
    """Per-sample errors of a run, shape (N,) each.

    orientation_error : rad, geodesic angle to the truth.
    angular_momentum_error : |L - L_truth| / max_t |L_truth| (or kg m^2/s absolute if that is 0).
    energy_error : |E - E_truth| / max_t KE_truth (or J absolute if that is 0).
    position_error : m, |x - x_truth|.
    """

    t: np.ndarray
    orientation_error: np.ndarray
    angular_momentum_error: np.ndarray
    energy_error: np.ndarray
    position_error: np.ndarray
    angular_momentum_relative: bool
    energy_relative: bool


def energies(problem: Problem, tr: Trajectory) -> tuple[np.ndarray, np.ndarray]:
    """(kinetic (N,), total (N,)) energy in J of a trajectory, canonical formulas."""
    M, I_b = problem.body.mass, problem.body.I_body
    ke = kinetic_energy(M, I_b, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity)
    return ke, ke + potential_energy(M, problem.gravity, tr.position)


def series(problem: Problem, tr: Trajectory, truth: Trajectory) -> Series:
    n = len(tr)
    truth = truth.head(n)
    I_b = problem.body.I_body
    ori = geodesic_angle(truth.quaternion_wxyz, tr.quaternion_wxyz)
    L = angular_momentum(I_b, tr.quaternion_wxyz, tr.angular_velocity)
    L_true = angular_momentum(I_b, truth.quaternion_wxyz, truth.angular_velocity)
    L_scale = float(np.max(np.linalg.norm(L_true, axis=-1)))
    dL = np.linalg.norm(L - L_true, axis=-1)
    _, E = energies(problem, tr)
    ke_true, E_true = energies(problem, truth)
    E_scale = float(np.max(ke_true))
    dE = np.abs(E - E_true)
    return Series(
        t=tr.t, orientation_error=ori,
        angular_momentum_error=dL / L_scale if L_scale > 0 else dL,
        energy_error=dE / E_scale if E_scale > 0 else dE,
        position_error=np.linalg.norm(tr.position - truth.position, axis=-1),
        angular_momentum_relative=L_scale > 0, energy_relative=E_scale > 0,
    )


def summarize(problem: Problem, tr: Trajectory, truth: Trajectory) -> tuple[dict, Series]:
    """The results.json ``metrics`` dict (maxima and finals) and the per-sample series."""
    s = series(problem, tr, truth)
    m = {
        ORIENTATION_ERROR_MAX: _max(s.orientation_error),
        ORIENTATION_ERROR_FINAL: finite_or_none(s.orientation_error[-1]),
        ANGULAR_MOMENTUM_ERROR_MAX_REL: _max(s.angular_momentum_error) if s.angular_momentum_relative else None,
        ENERGY_ERROR_MAX_REL: _max(s.energy_error) if s.energy_relative else None,
        POSITION_ERROR_MAX: _max(s.position_error),
        ROTATION_ORTHONORMALITY_ERROR_MAX: (
            None if tr.orthonormality_error is None else _max(tr.orthonormality_error)),
    }
    if not s.angular_momentum_relative:
        m[ANGULAR_MOMENTUM_ERROR_MAX_ABS] = _max(s.angular_momentum_error)
    if not s.energy_relative:
        m[ENERGY_ERROR_MAX_ABS] = _max(s.energy_error)
    return m, s


def divergence(problem: Problem, tr: Trajectory, truth: Trajectory) -> tuple[float, str] | None:
    """(time, reason) of the first sample that is non-finite or beyond the case's bounds, or None.

    Bounds: kinetic energy > DIVERGENCE_ENERGY_FACTOR x the truth's max KE, |w| or |v| beyond
    their factor x the truth's max, and for an integrated rotation matrix ||R^T R - 1||_F beyond
    DIVERGENCE_ORTHONORMALITY_MAX (see :mod:`freebody.tolerances`): the earlier of that and the others.
    """
    found = _state_divergence(problem, tr, truth)
    ortho = None if tr.orthonormality_error is None else _first(
        tr.orthonormality_error > tol.DIVERGENCE_ORTHONORMALITY_MAX)
    if ortho is not None and (found is None or tr.t[ortho] < found[0]):
        return (float(tr.t[ortho]), f"R is no rotation: ||R^T R - 1||_F beyond "
                                    f"{tol.DIVERGENCE_ORTHONORMALITY_MAX:g}")
    return found


def _state_divergence(problem: Problem, tr: Trajectory, truth: Trajectory) -> tuple[float, str] | None:
    """The state's part of :func:`divergence`: non-finite samples first, then the bounds."""
    n = len(tr)
    truth = truth.head(n)
    arrays = (tr.position, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity)
    bad = ~np.all(np.concatenate([np.isfinite(a) for a in arrays], axis=1), axis=1)
    first = _first(bad)
    if first is not None:
        return float(tr.t[first]), "state is not finite (NaN or inf)"
    ke, _ = energies(problem, tr)
    ke_true, _ = energies(problem, truth)
    ke_bound = tol.DIVERGENCE_ENERGY_FACTOR * max(float(np.max(ke_true)), tol.DIVERGENCE_ENERGY_FLOOR_J)
    w_norm = np.linalg.norm(tr.angular_velocity, axis=1)
    w_bound = tol.DIVERGENCE_OMEGA_FACTOR * max(float(np.max(np.linalg.norm(truth.angular_velocity, axis=1))),
                                                tol.DIVERGENCE_OMEGA_FLOOR_RAD_S)
    v_norm = np.linalg.norm(tr.linear_velocity, axis=1)
    v_bound = tol.DIVERGENCE_VELOCITY_FACTOR * max(float(np.max(np.linalg.norm(truth.linear_velocity, axis=1))),
                                                   tol.DIVERGENCE_VELOCITY_FLOOR_M_S)
    for mask, why in ((ke > ke_bound, f"kinetic energy beyond {ke_bound:.3g} J"),
                      (w_norm > w_bound, f"|w| beyond {w_bound:.3g} rad/s"),
                      (v_norm > v_bound, f"|v| beyond {v_bound:.3g} m/s")):
        first = _first(mask)
        if first is not None:
            return float(tr.t[first]), why
    return None


def _first(mask: np.ndarray) -> int | None:
    idx = np.flatnonzero(mask)
    return int(idx[0]) if idx.size else None


def _max(a: np.ndarray) -> float | None:
    return finite_or_none(np.max(a)) if len(a) else None
