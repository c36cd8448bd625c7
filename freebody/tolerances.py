"""Named numerical constants of the harness, each with the reason for its value.

Test tolerances live beside the tests that use them; these are the ones the harness itself applies.
"""
from __future__ import annotations

# --- divergence (a run's status) ------------------------------------------------------------
DIVERGENCE_ENERGY_FACTOR = 1e6  # KE beyond 1e6 x the truth's max KE: no integrator error is that big
DIVERGENCE_ENERGY_FLOOR_J = 1e-9  # energy scale for a body at rest (truth KE = 0)
DIVERGENCE_OMEGA_FACTOR = 1e3  # |w| beyond 1e3 x the truth's max |w| (floor 1 rad/s): blown up
DIVERGENCE_VELOCITY_FACTOR = 1e3  # |v| beyond 1e3 x the truth's max |v| (floor 1 m/s): blown up

# --- case validation ------------------------------------------------------------------------
TRIANGLE_INEQUALITY_RTOL = 1e-12  # I1 + I2 >= I3 (1 - rtol): planar bodies such as diag(1,2,3) pass
SYMMETRY_RTOL = 1e-12  # |I - I^T| <= rtol |I|: inertia tensors are symmetric up to rounding
UNIT_QUATERNION_RTOL = 1e-9  # | |q| - 1 | above this: normalise with a warning

# --- scheme identification -------------------------------------------------------------------
SCHEME_MATCH_RAD = 1e-6  # an engine "reproduces" a reference map if its orientation stays within
                         # 1e-6 rad of it: round-off differences between float64 codes stay far below
