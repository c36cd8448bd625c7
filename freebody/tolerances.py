"""Every numerical threshold of the harness, each a named constant with the reason for its value
(which method, which time step, which horizon).

A leaf module: it holds constants only and imports nothing from freebody, so every layer (input,
run, results, report, tools, cli, and the engine adapters: ``from ..tolerances import X``) may
import it.  Test tolerances live beside the tests that use them; numerical constants of the
reference algorithms (series cut-offs, iteration limits in ``reference_impl/``) live with them.
"""
from __future__ import annotations

# --- accuracy of the truth and of float64 round-off ----------------------------------------------
# The orientation accuracy of the truth.  Measured: the closed form and the numerical truth (DOP853
# at rtol = atol = 1e-12 in body-frame variables) agree to 2.8e-10 rad on dzhanibekov over 10 s at
# dt = 0.01 (and 0.001).  1e-9 rounds that up (x ~3.6) for other bodies and horizons; the tests
# (tests/test_torque_free.py, tests/test_reference_integrators.py) assert with a looser 2e-9 budget.
# An orientation error below this says nothing about the engine.
TRUTH_ORIENTATION_ACCURACY_RAD = 1e-9
TRUTH_POSITION_ACCURACY_M = 1e-9  # the numerical truth's position accuracy (DOP853 at rtol = atol = 1e-12)
# Round-off of a relative quantity (E, |L|) accumulated over 1e3-1e4 float64 steps.
FLOAT64_ACCUMULATED_ROUNDOFF_REL = 1e-12
# float32 runs hit round-off far earlier: ~1e-7 per step accumulated over ~1e2-1e4 steps.
FLOAT32_ACCUMULATED_ROUNDOFF = 1e-5

# --- divergence (a run's status) ----------------------------------------------------------------
DIVERGENCE_ENERGY_FACTOR = 1e6  # KE beyond 1e6 x the truth's max KE: no integrator error is that big
DIVERGENCE_ENERGY_FLOOR_J = 1e-9  # energy scale for a body at rest (truth KE = 0)
DIVERGENCE_OMEGA_FACTOR = 1e3  # |w| beyond 1e3 x the truth's max |w| (floored below): blown up
DIVERGENCE_OMEGA_FLOOR_RAD_S = 1.0  # |w| scale of a body that does not spin (truth |w| = 0)
DIVERGENCE_VELOCITY_FACTOR = 1e3  # |v| beyond 1e3 x the truth's max |v| (floored below): blown up
DIVERGENCE_VELOCITY_FLOOR_M_S = 1.0  # |v| scale of a body at rest (truth |v| = 0)

# --- case validation ----------------------------------------------------------------------------
TRIANGLE_INEQUALITY_RTOL = 1e-12  # I1 + I2 >= I3 (1 - rtol): planar bodies such as diag(1,2,3) pass
SYMMETRY_RTOL = 1e-12  # |I - I^T| <= rtol |I|: inertia tensors are symmetric up to rounding
UNIT_QUATERNION_RTOL = 1e-9  # | |q| - 1 | above this: normalise with a warning
# A duration shorter than dt by less than this fraction is one step (decimal-to-binary rounding of
# the two numbers), not "shorter than dt": case files, ``freebody run --dt``, ``freebody sweep``.
DURATION_VS_DT_RTOL = 1e-12

# --- scheme identification ----------------------------------------------------------------------
SCHEME_MATCH_RAD = 1e-6  # an engine "reproduces" a reference map if its orientation stays within
                         # 1e-6 rad of it: round-off differences between float64 codes stay far below

# --- observed order of convergence (run/convergence.py) -----------------------------------------
# A point is left out of the fit outside (floor, saturation): below the floor its error is the
# truth's inaccuracy or round-off, above the saturation it no longer depends on dt.
CONVERGENCE_ORIENTATION_SATURATED_RAD = 1.0  # an error of order pi (> 1 rad) is "lost", not O(dt^p)
CONVERGENCE_ORIENTATION_FLOOR_RAD = TRUTH_ORIENTATION_ACCURACY_RAD  # below: the truth's own error
CONVERGENCE_ENERGY_SATURATED_REL = 1.0  # an energy error as large as the kinetic energy itself
CONVERGENCE_ENERGY_FLOOR_REL = FLOAT64_ACCUMULATED_ROUNDOFF_REL  # below: float64 round-off
CONVERGENCE_ORIENTATION_FLOOR_FLOAT32_RAD = FLOAT32_ACCUMULATED_ROUNDOFF  # float32 runs: round-off
CONVERGENCE_ENERGY_FLOOR_FLOAT32_REL = FLOAT32_ACCUMULATED_ROUNDOFF  # float32 runs: round-off
# Horizons steps x dt rounded to this many decimals (1e-12 s) before they are compared: the same
# horizon reached at two time steps differs only by the rounding of the product.
CONVERGENCE_HORIZON_DECIMALS = 12

# --- regression gate (``freebody compare``; see docs/ci-gate.md) ---------------------------------
# A metric regresses when current > baseline + atol + rtol * |baseline| (every compared metric is
# an error: lower is better).  A TOML file (``--tolerances``) or ``--rtol``/``--atol`` override these.
# Same engine version, another CPU or BLAS: errors move by round-off, far below 1 %; a changed
# scheme, default or setting moves them by factors.  1 % separates the two.
COMPARE_DEFAULT_RTOL = 0.01
# Absolute floors, one per metric, in the metric's unit: below these, a change is noise.
COMPARE_ORIENTATION_ATOL_RAD = TRUTH_ORIENTATION_ACCURACY_RAD  # the truth's own accuracy
COMPARE_MOMENTUM_ATOL_REL = FLOAT64_ACCUMULATED_ROUNDOFF_REL  # round-off of |L| over 1e3-1e4 steps
COMPARE_MOMENTUM_ATOL_ABS = 1e-12  # kg m^2/s, for bodies at rest (L = 0): the same round-off, absolute
COMPARE_ENERGY_ATOL_REL = FLOAT64_ACCUMULATED_ROUNDOFF_REL  # round-off of E over 1e3-1e4 steps
COMPARE_ENERGY_ATOL_ABS_J = 1e-12  # J, for bodies at rest: the same round-off, absolute
COMPARE_POSITION_ATOL_M = TRUTH_POSITION_ACCURACY_M  # the numerical truth's position accuracy
COMPARE_ORTHONORMALITY_ATOL = 1e-12  # ||R^T R - 1||_F of a re-orthonormalised matrix is round-off, ~1e-15
# A baseline run and a current run match when their dt agree to this many significant digits (a dt
# that went through another tool's decimal formatting still matches; distinct dts differ far earlier).
COMPARE_DT_SIGNIFICANT_DIGITS = 12

# --- convention self-checks (run/selfcheck.py, ``freebody conventions``) -------------------------
SELFCHECK_INITIAL_STATE_ATOL = 1e-12  # reading back what was just set: conversions only, round-off
# One step of h = 1e-3 from rest with a push: the engines' maps change L by h tau to within
# O(h^2 |tau| / I) (the rotation of the body during the step), far below this relative bound;
# a wrong frame or sign of the arm is an O(1) error.
SELFCHECK_PUSH_TORQUE_RTOL = 1e-3
# A torque-free spin keeps L as well as the reference map the engine implements: allow 10% over
# the better of the candidate maps (their L errors differ by orders of magnitude from the truth's).
SELFCHECK_L_DRIFT_FACTOR = 1.1
# Relative L error floor: round-off over 2 s at dt = 1e-3 (2000 float64 steps).
SELFCHECK_L_DRIFT_ATOL = FLOAT64_ACCUMULATED_ROUNDOFF_REL
# A spin about a principal axis has no gyroscopic term: the engines' exponential-map update is
# exact, so only round-off (and a clamp or per-step rotation cap, if any) separates it from truth
# (the exact rotation, not the numerical truth: hence not TRUTH_ORIENTATION_ACCURACY_RAD, although
# the value is the same); an RK4 engine may in addition show RK4's own error (the reference rk4's,
# times SELFCHECK_L_DRIFT_FACTOR).
SELFCHECK_HIGH_SPIN_RAD = 1e-9

# --- engine adapters: read-back checks of the built model ----------------------------------------
# MuJoCo.  A flat body (A + B = C exactly, e.g. diag(1, 2, 3)) with off-diagonal terms fails
# MuJoCo's "A + B >= C" check about a third of the time through round-off in the diagonalisation;
# such a violation up to this fraction of C is treated as round-off.
MUJOCO_TRIANGLE_ROUNDOFF = 1e-12
# The principal axes turned into a quaternion and back reproduce the eigenvector matrix to
# round-off (absolute, on entries of magnitude <= 1; np.allclose's default rtol applies as well).
MUJOCO_PRINCIPAL_AXES_ATOL = 1e-12
# DART: relative tolerance for the values the adapter wrote (mass, inertia, pose, velocities,
# gravity, time step), all copied or converted in float64.
DART_READBACK_RTOL = 1e-9
# DART: a probe state read back in DART's FreeJoint coordinates matches [log R; x] and [w; v] in
# the right frame to round-off (max abs difference); the wrong frame differs by O(1).
DART_FRAME_PROBE_ATOL = 1e-12
# PyBullet.  Values set through the API come back bit-exact or to a few ulps; the probe step of a
# spin about a principal axis keeps |w| to ~1e-14 relative (the gyroscopic term of a spin about a
# rounded principal axis), while damping 0.04 or the clamp change it by > 1e-6 at any dt.
PYBULLET_READBACK_RTOL = 1e-12
PYBULLET_PROBE_RTOL = 1e-9
PYBULLET_INITIAL_STATE_RTOL = 1e-9  # build() re-reads the initial state (measured ~5e-16)
# PyBullet: I_body = V diag(d) V^T rebuilt from numpy's eigen-decomposition agrees to round-off
# (relative, and absolute in units of the largest principal moment).
PYBULLET_EIGEN_RTOL = 1e-12
PYBULLET_EIGEN_ATOL_REL = 1e-14

# --- tools and displays -------------------------------------------------------------------------
# ``freebody demo``: fit convergence slopes only to errors above float64 round-off and below
# saturation (explicit Euler's error over 2 s stays < 0.2 rad at the demo's time steps).
DEMO_SLOPE_FIT_RANGE_RAD = (1e-12, 0.3)
# ``freebody inertia``: shown as 0, entries below this fraction of their array's scale are rounding
# noise of the integration (e.g. 1e-22 off-diagonals of a symmetric body); the JSON keeps the raw numbers.
INERTIA_DISPLAY_ZERO_RTOL = 1e-12
# ``freebody inertia``: plotted errors below this are rounding noise (e.g. the COM of a symmetric shape).
INERTIA_PLOT_NOISE_FLOOR = 1e-12
# Report plots: a log-axis tick whose log10 is within this of an integer is labelled as a decade.
PLOT_DECADE_TICK_ATOL = 1e-9
