"""Every numerical threshold of the harness, each a named constant with the reason for its value
(which method, which time step, which horizon).

A leaf module: it holds constants only and imports nothing from freebody, so every layer (input,
run, results, report, tools, cli, and the engine adapters: ``from freebody.tolerances import X``)
may import it.  An engine's own bounds (read-back and trap checks) live in its adapter module,
beside the checks.  Test tolerances live beside the tests that use them; numerical constants of the
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
# A blow-up (a finding, the run stays ok: run/metrics.GrowthStats, report/findings.py "blow-up"): an
# ok run whose max |w| exceeds BLOW_UP_OMEGA_FACTOR x the truth's max |w| (floored as above), or whose
# max kinetic energy exceeds BLOW_UP_ENERGY_FACTOR x the truth's max KE (floored as above).  Measured
# on the bundled cases at their default dts (MuJoCo 4.0.0, PyBullet 3.2.7, DART 6.20, Drake 1.51,
# SAPIEN 3, the reference maps; 1161 runs): every bounded run is within 2.4x of the truth's max |w|
# and 2.1x of its max KE; the runs beyond are blow-ups, nothing in between (3x to 15x): the explicit
# gyroscopic term on thin_rod at dt = 0.01 (MuJoCo Euler, PyBullet multibody, DART, Drake discrete
# and semi-explicit-euler, the map: KE x141 at |w| x2.3, the stiff gyroscopic term's energy blow-up),
# fully explicit Euler (lie-euler, euler-quat, euler-matrix-gs) on thin_rod (|w| x61-296, KE
# x71-1.6e3) and on flat_plate at dt = 0.01 (|w| x16, KE x32-34); the explicit-gyro engines on a thin
# disk spun at 20 rad/s, tilted 30 deg, dt = 0.01, 5 s: |w| x797, KE x6.5e3 (|w| beyond 20x from
# t = 2.5 s).  20x |w| and 10x KE sit in the gap.
BLOW_UP_OMEGA_FACTOR = 20.0
BLOW_UP_ENERGY_FACTOR = 10.0
# An ok run whose largest |1 - |q_k|| (the quaternions as the engine handed them out, before the
# harness normalises anything: run/metrics "quaternion_norm_error_max") is beyond this, per
# precision, returns non-unit quaternions (a finding, report/findings.py "non-unit-quaternion").
# Measured on every sample of dzhanibekov(_rotated), high_spin_dt_10ms, thin_rod, long_horizon and
# gazebo_boxes_simple (243 runs): float64 at most 1.2e-15 (MuJoCo RK4; PyBullet 4.4e-16, the reference
# maps, DART and Drake's q / |q| 3.3e-16), float32 at most 3.5e-7 (SAPIEN pgs, dzhanibekov_rotated,
# 1e4 steps; MJX float32 1.6e-7 on the default suite's saved samples), a few ulps of a unit q.  1e-12 and
# 1e-5 leave ~1e3x and ~30x of margin for longer runs (newton's float32 q, 2.5e-8 above 1, is
# within); a norm drift an engine lets grow (Drake's raw |q| reaches 1.41 in 10 s) is far beyond.
QUATERNION_NORM_ROUNDOFF = {"float64": 1e-12, "float32": 1e-5}

# --- case validation ----------------------------------------------------------------------------
TRIANGLE_INEQUALITY_RTOL = 1e-12  # I1 + I2 >= I3 (1 - rtol): planar bodies such as diag(1,2,3) pass
SYMMETRY_RTOL = 1e-12  # |I - I^T| <= rtol |I|: inertia tensors are symmetric up to rounding
UNIT_QUATERNION_RTOL = 1e-9  # | |q| - 1 | above this: normalise with a warning
# A duration shorter than dt by less than this fraction is one step (decimal-to-binary rounding of
# the two numbers), not "shorter than dt": case files, ``freebody run --dt``, ``freebody sweep``.
DURATION_VS_DT_RTOL = 1e-12

# --- representable inputs (case files, meshes, command-line options) ---------------------------
# Every number of a case (and ``freebody inertia``'s sizes and densities) is at most this in
# magnitude: the squares and pairwise products the physics forms (|w|^2, I w, the size^2 in a
# shape's inertia, the eigen-decomposition of I) then stay finite in float64 (largest 1.8e308).  Far
# beyond any body: the observable universe is ~1e27 m across and ~1e53 kg.
INPUT_MAGNITUDE_MAX = 1e150
# Positive quantities (mass, density, sizes, dt, a body's volume and principal moments) are at least
# this: their squares and reciprocals stay normal float64 numbers (smallest normal 2.2e-308), so a
# 1e-320 is not silently a zero (or its reciprocal an infinity).
INPUT_POSITIVE_MIN = 1e-150
# Mesh coordinates (m) are at most this in magnitude: the polyhedral mass-property integrals multiply
# five coordinates (a determinant times a quadratic), and (1e60)^5 = 1e300 stays finite in float64.
MESH_COORDINATE_MAX = 1e60
# Steps of one run at most this (round(duration / dt), duration_steps, --save-every): 1e9 steps are
# ~100 GB of trajectory samples and hours of stepping; beyond, a run can neither finish nor be
# stored (numpy refuses the arrays: "Maximum allowed dimension exceeded").
MAX_STEPS_PER_RUN = 10**9

# --- scheme identification: see SCHEME_ROUNDOFF_FACTOR below (a round-off level per case) --------

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
# Orientation errors above 1 rad on both sides compare equal: the orientation is lost (a blown-up or
# long chaotic run), and where in [1, pi] it ends is round-off amplified (spinning_sphere's
# euler-matrix at dt 0.01 moves from 2.74 to 3.10 rad with summation order alone).
COMPARE_ORIENTATION_SATURATED_RAD = 1.0
# A fitted order of convergence that moves by more than this is a change of scheme (first to
# second order is 1; fits of one scheme on different machines agree to about 0.01).
COMPARE_ORDER_CHANGE = 0.5

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
# Engines that offer float32 only (SAPIEN) run the checks in float32.  t = 0 read-back: float32
# storage of values up to ~3 (eps32 1.2e-7; measured 4.8e-8).
SELFCHECK_INITIAL_STATE_FLOAT32_ATOL = 1e-6
# The high spin (150 rad/s, 200 steps, 30 rad) in float32: measured 2.8e-5 rad (SAPIEN pgs) and
# 1.9e-3 (tgs, whose |w| grows ~5e-7 a step: 1.3e-4 over the run); a 100 rad/s clamp would be
# 10 rad off.
SELFCHECK_HIGH_SPIN_FLOAT32_RAD = 1e-2

# --- engine adapters -------------------------------------------------------------------------
# An engine's own bounds (its read-back checks of the built model, its trap checks) live in its
# adapter module next to the checks that use them (e.g. adapters/sapien_adapter.py SAPIEN_TRAP_*;
# MuJoCo's inertia conversion in adapters/mjcf.py), so a third-party adapter adds its own beside its
# checks.  This module keeps the harness's rules.  (No harness module uses an engine's bound.)

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

# --- input files: regular files only, and how large (freebody/results/io.read_regular_file) -------
# Every file freebody reads must be a regular file (a FIFO would block forever, /dev/zero or
# /dev/urandom would be read until memory runs out) no larger than these.  Measured peaks are of
# Python's allocations (tracemalloc) while parsing, per byte of the file.
MIB = 2 ** 20
# A closed OBJ/STL mesh (``body.mesh``, ``freebody inertia PATH``).  128 MiB is ~2.7 million
# triangles of binary STL (50 bytes each), or an OBJ of ~2.5 million: far finer than exact mass
# properties need.  Parsing peaks at ~12 bytes per file byte (binary STL; OBJ ~8.4): ~1.5 GiB.
MESH_FILE_MAX_BYTES = 128 * MIB
# A case file: a few hundred bytes; 16 MiB leaves room for generated cases with ~1 million time
# steps or loads.  tomllib peaks at ~2.3 bytes per byte (~40 MiB).
CASE_FILE_MAX_BYTES = 16 * MIB
# A results.json or baseline (``freebody compare``, ``freebody report``): ~1.9 KB per run, so
# 512 MiB is ~280,000 runs (380 x the default suite's 735).  json.loads peaks at ~3.2 bytes per
# byte: ~1.6 GiB per document, two for a comparison.  Also sweep.json.
RESULTS_FILE_MAX_BYTES = 512 * MIB
# A ``--tolerances`` file: a few dozen lines.
TOLERANCES_FILE_MAX_BYTES = 1 * MIB

# --- resource estimates before a command starts (freebody/run/budget.py) -------------------------
# A command whose estimated memory exceeds the memory available (MemAvailable of /proc/meminfo) is
# refused (exit 2) unless ``--force-large``; one whose estimated time exceeds LONG_RUN_WARNING_S is
# run with a warning.  The constants below were measured on this project's 2-core test machine with
# tracemalloc (memory) and wall clocks (time), and rounded up.
# A run's arrays in its worker: its trajectory, its truth (14 float64 per step each), the seven
# reference maps' orientations and round-off spreads (scheme identification, 5 float64 per step
# each), the error series and the copies made while saving.  Measured peaks: 480 (reference rk4)
# to 842 (mujoco, identified against seven maps) bytes per step; 9 trajectories' worth, 1008 bytes
# per step, covers them.
RUN_BYTES_PER_STEP = 9 * 14 * 8
# A run of more than CHUNKED_JUDGING_MIN_STEPS steps is stepped and judged in chunks of
# JUDGE_CHUNK_STEPS steps (run/execute.py, run/judge.RunJudge): its memory is that of one chunk
# (~1 KB a step as above: ~100 MB) plus the samples its trajectory file keeps, whatever its length
# (measured peak RSS of a 1e7-step MuJoCo run: see docs/parallel.md).  Shorter runs are judged whole,
# their truth and reference maps computed once per (case, dt, steps) group and shared by the
# group's runs (a chunked run computes its own, and its truth twice: a first pass for the maxima
# that scale the errors and bound the divergence); 200,000 steps (~200 MB) keeps every run of the
# default suite (at most 100,000 steps) on that path.  100,000 steps a chunk keep the per-chunk
# overhead (numpy calls, the 28 reference runs of identification resumed) below 1% of the work.
CHUNKED_JUDGING_MIN_STEPS = 200_000
# The engine-equivalent maps (reference_impl.engine_maps) are integrated whole, not continued chunk
# by chunk: scheme identification compares them with runs of at most this many steps only, so that
# a long run's memory stays bounded by its chunk (their whole runs, 16 streams of q, would not).
ENGINE_MAP_CANDIDATES_MAX_STEPS = 200_000
JUDGE_CHUNK_STEPS = 100_000
# A run judged whole but longer than PROGRESS_PIECE_MIN_STEPS steps is stepped in pieces of
# PROGRESS_PIECE_STEPS (run/execute._simulate) so the progress display can show its steps done (a
# Drake rk5 run of 100,000 steps takes minutes).  The pieces are the one-shot run bit for bit (the
# chunks contract); 10,000 is a multiple of MJX's and Brax's compiled scan length (1000 steps), so
# no piece costs them a compilation, and a piece's overhead (one advance call, one copy) is < 0.1%.
PROGRESS_PIECE_MIN_STEPS = 20_000
PROGRESS_PIECE_STEPS = 10_000
# What the freebody process keeps per run (the spec, the result, results.json being written):
# measured 12.4 KB per run (2000 runs of 2 steps) at the peak.
RUN_RECORD_BYTES = 16 * 1024
# freebody sweep: a body (its problem, its case-file text, its record): measured 4.3 KB.
SWEEP_BODY_BYTES = 8 * 1024
# Time: the default suite (735 runs, 4.2e6 steps, all five engines) ran in 268 s with --jobs 1:
# 64 us per step on average (the reference engine's Python loops and the truths dominate); a run
# of 2 steps costs 7-9 ms (worker messages, truth, metrics, its file).
SECONDS_PER_STEP = 64e-6
SECONDS_PER_RUN = 0.01
LONG_RUN_WARNING_S = 3600.0  # an estimate beyond an hour is said before the runs start
# freebody inertia --method particles|voxels (--compare: its finest resolution): bytes per grid
# cell at the peak.  Measured: voxels 65 (sphere) to 97 (box) for shapes, 29-55 for meshes;
# particles 105-144 for shapes, ~120 per cell for meshes beyond their fixed part.
INERTIA_BYTES_PER_CELL = {"voxels": 112, "particles": 192}
# The mesh inside test works in vectorised blocks of ~100 MB (reference_impl/approx.py): measured
# up to ~150 MB beyond the per-cell part.
INERTIA_MESH_FIXED_BYTES = 256 * MIB

# --- honest scheme identification (run/judge.identify) and divergence of a matrix's R ------------
# A reference map M reproduces an engine run when, at every sample t_k, the run's orientation is
# within M's round-off level on the case of M's own:
#     angle(q_run(t_k), q_M(t_k)) <= max(SCHEME_ROUNDOFF_FACTOR * max_{j<=k} s_M(t_j), SCHEME_ROUNDOFF_FLOOR_RAD)
# s_M is how the case amplifies round-off: the largest orientation difference between M's run and
# M's runs from four starts one ulp away (in the run's precision: every component of the initial
# q, w, x, v and of I_body moved by one ulp of its vector's largest entry, q renormalised; four
# orthogonal sign patterns, since at a given time a flip amplifies some directions far more than
# others).  dt and the loads' step ranges are the case's: round-off does not move a load's switch
# by a step (a dt one ulp away did, Load.step_range: levels of 0.6-5.7 rad on offset_push).  The four
# directions are orthogonal (three patterns, two of them each other's negatives, gave two maps
# 2e-10 rad apart on dzhanibekov_rotated levels 18x apart; these give them 2.8e-10 and 3.2e-10).  A steady spin keeps it near 1e-15; a flip (dzhanibekov) grows it to 5e-10 over
# 10 s and to 0.4 rad over 1e6 steps.  Compared sample by sample (the spread's running maximum), so
# no map matches a chaotic run merely because the orientation is lost at its end.  Maps reproducing
# a run that are within their levels of each other are indistinguishable on the case: a tie (a
# sphere, a spin about a principal axis).
# The factor: another float code of the same map rounds differently at every step, not once at the
# start.  Measured on the default suite (MuJoCo 4.0.0, MJX 3.17, DART 6.20, PyBullet 3.2.7), in units
# of s_M: the numpy loops of each reference map against its compiled code <= 8.4; the engines'
# float64 integrators against their maps <= 26 (MuJoCo), 30 (MJX), 47 (DART), 17 (PyBullet
# multibody), 15-340 (PyBullet maximal coordinates, growing with the horizon); MuJoCo Euler on
# dzhanibekov for 1e6 steps at dt = 1e-3 2.4 (0.53 rad apart).  A different map differs by its
# truncation error: MuJoCo 4.0's fourth-order RK4 from the reference rk4 at dt = 1e-3, 159 to 2.9e4
# (40 on world_torque, where their O(dt^4) difference is below round-off: reproduced), MJX's
# second-order RK4 >= 3.6e6.  100 sits between the two (2x from each side): PyBullet's maximal
# coordinates are reproduced on the shorter horizons only.
SCHEME_ROUNDOFF_FACTOR = 100.0
# Below this nothing is distinguishable whatever the case: a few dozen ulps of a unit quaternion,
# what two float64 codes differ by in forming the same rotation (a conversion, a normalisation).
SCHEME_ROUNDOFF_FLOOR_RAD = 1e-14
# A level is at most this: beyond ~0.1 rad the spread of one-ulp starts no longer grows linearly
# with the perturbation (the orientations' difference saturates towards pi), so it no longer
# measures round-off, and a level that large would accept maps that differ by their whole scheme.
# A map whose level reaches it (dzhanibekov over 1e6 steps: 100 x 0.4 rad), or whose perturbed copies
# or own run are not finite (an unstable spin), identifies nothing on the case from there:
# "undecidable" (run/judge.identify), never a tie.
SCHEME_ROUNDOFF_LEVEL_MAX_RAD = 0.1
# A float32 code may round the same way at every step: |w| then drifts by up to an ulp a step
# (FLT_EPSILON = 2^-23 relative) and the orientation by up to beta x k x theta_k / 2 after k steps,
# theta_k the angle the map turned through.  The level of a float32 run is at least that (a
# float64 code's drift is within SCHEME_ROUNDOFF_FACTOR x s_M, measured above).  Measured: SAPIEN 3
# pgs (PhysX, float32) on gazebo_boxes_simple at dt = 1e-3 (0.5 rad/s, 1e4 steps) drifts |w| by
# -3.1e-8 a step (0.26 ulp) and its orientation 8.2e-4 rad from PhysX's float64 map (0.28 x the bound),
# 100 x s_M being 1.5e-4; on the other loaded cases 0.02-0.25 x the bound.  SAPIEN tgs's solver bias
# (sapien_adapter.SAPIEN_TGS_SPIN_DRIFT_PER_STEP, 5e-7 a step) is beyond it: an engine property, not
# round-off.
SCHEME_ROUNDING_DRIFT_PER_STEP = {"float32": 2.0 ** -23, "float64": 0.0}
# A lone map M "reproduces" a run only when every other (decidable) map's ratio (max distance over
# its own level) is at least this many times M's: a run within M's level at ratio r while another
# map is at less than 3 r sits between the maps, not on one, and is only "closest: M".  Measured on
# the default suite: MJX RK4 float32 dzhanibekov dt 1e-3 was within quat-rate-rk2's 5.9e-2 rad level
# at 0.98 with quat-rate-cayley-gyro at 1.83 (MJX's own map, rk4-body-exp, 0.15 rad away: a false
# "reproduces"); every other lone verdict of the suite is separated by 7.8x (SAPIEN pgs offset_push
# dt 1e-3, PhysX's map at 0.36, the next at 2.77) or more.
SCHEME_SEPARATION_RATIO = 3.0
# A rotation matrix integrated without correction (reference euler-matrix) is diverged once
# ||R^T R - 1||_F exceeds this.  Explicit Euler stretches R perpendicular to the spin (singular
# values sqrt(1 + h^2 |w|^2) per step); at 1 the stretched axes' squared lengths are ~1.7 (lengths
# +30%, volumes x1.7), so the inertia R I_b R^T and the angular velocity R I_b^-1 R^T L the scheme
# computes through R are off by a factor of order 1: R is no rotation in any useful sense.  Below
# it the drift is the scheme's own error, which the teaching runs show.  Default suite: the ok
# euler-matrix runs drift to 0.004-0.92; flat_plate, projectile, stable_minor_axis and
# symmetric_top at dt = 0.01 reach 1.2-6.5 and t_handle at 1e-3 2.0, high_spin_dt_1ms 6.5e9,
# high_spin_dt_10ms 3e102 (after one step: 3.2).
DIVERGENCE_ORTHONORMALITY_MAX = 1.0

# How long a plug-in's adapter module (an entry point of freebody.adapters) may take to import in
# its probe process when ``run --timeout`` is not given: the slowest built-in engine imports (JAX,
# pydrake) take 2-10 s on a loaded 2-core machine; a minute is a hang, not a slow import.
# $FREEBODY_PLUGIN_IMPORT_TIMEOUT overrides it.
PLUGIN_IMPORT_TIMEOUT_S = 60.0
