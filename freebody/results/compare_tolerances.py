"""Default tolerances of ``freebody compare``: a metric regresses when

    current > baseline + atol + rtol * |baseline|

(every compared metric is an error: lower is better).  Each constant gives the reason for its value.
A TOML file (``--tolerances``) or ``--rtol``/``--atol`` override them (see docs/ci-gate.md).
"""
from __future__ import annotations

# Same engine version, another CPU or BLAS: errors move by round-off, far below 1 %; a changed
# scheme, default or setting moves them by factors.  1 % separates the two.
DEFAULT_RTOL = 0.01

# Absolute floors, one per metric, in the metric's unit: below these, a change is noise.
ORIENTATION_ATOL_RAD = 1e-9  # the truth's own accuracy (numerical vs closed form agree to 2e-9 rad)
MOMENTUM_ATOL_REL = 1e-12  # round-off of |L| accumulated over 1e3-1e4 float64 steps
MOMENTUM_ATOL_ABS = 1e-12  # kg m^2/s, for bodies at rest (L = 0): the same round-off, absolute
ENERGY_ATOL_REL = 1e-12  # round-off of E over 1e3-1e4 float64 steps
ENERGY_ATOL_ABS_J = 1e-12  # J, for bodies at rest: the same round-off, absolute
POSITION_ATOL_M = 1e-9  # the numerical truth's position accuracy (DOP853 at rtol = atol = 1e-12)
ORTHONORMALITY_ATOL = 1e-12  # ||R^T R - 1||_F of a re-orthonormalised matrix is round-off, ~1e-15

METRIC_ATOL = {
    "orientation_error_max_rad": ORIENTATION_ATOL_RAD,
    "orientation_error_final_rad": ORIENTATION_ATOL_RAD,
    "orientation_error_max_before_divergence_rad": ORIENTATION_ATOL_RAD,
    "angular_momentum_error_max_rel": MOMENTUM_ATOL_REL,
    "angular_momentum_error_max_abs": MOMENTUM_ATOL_ABS,
    "energy_error_max_rel": ENERGY_ATOL_REL,
    "energy_error_max_abs_J": ENERGY_ATOL_ABS_J,
    "position_error_max_m": POSITION_ATOL_M,
    "rotation_orthonormality_error_max": ORTHONORMALITY_ATOL,
}
COMPARED_METRICS = tuple(METRIC_ATOL)  # wall time is never compared: it measures the machine
