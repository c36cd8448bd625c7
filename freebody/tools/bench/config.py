"""The targets ``freebody bench`` checks (issue 29, with the older ones it keeps) and what one run
measures (:class:`BenchConfig`)."""
from __future__ import annotations

from dataclasses import dataclass

CASE = "dzhanibekov"             # torque-free, no gravity, no loads: the engines' bare step
DT = 0.001                       # s

# --- targets of issue 29 ------------------------------------------------------------------------------
TARGET_MARGINAL_RUN_CPU_S = 0.005   # overhead: one further 10-step run in an invocation, CPU s
TARGET_ONE_RUN_CPU_S = 1.2          # overhead: a one-run invocation, imports included, CPU s
TARGET_SUITE_VS_STEPPING = 4.0      # suite (without MJX): wall <= 4 x its runs' engine stepping
TARGET_MJX_VS_MUJOCO = 2.0          # suite: MJX's stepping <= 2 x MuJoCo's, warm
TARGET_COLD_COMPILE_CPU_S = 8.0     # first run: numba compilation for the quick start, CPU s
TARGET_TRUTH_VS_COMPILED = 3.0      # truth: DOP853 truth <= 3 x a numba-rhs DOP853, same tolerances
TARGET_MAP_VS_FLOOR = 1.5           # maps: semi-implicit maps <= 1.5 x a flat loop of their arithmetic
TARGET_OTHER_MAP_VS_FLOOR = 3.0     # maps: rk4, splitting, midpoint, rkmk4 <= 3 x theirs
TARGET_SWEEP_VS_ROLLOUT = 0.1       # sweep: body-steps/s >= 1/10 of mujoco.rollout's, same bodies
TARGET_SWEEP_JOBS_GAIN = 1.6        # sweep: --jobs 2 >= 1.6 x faster than --jobs 1 (wall)
TARGET_REPORT_VS_RUN = 0.1          # report: rendering <= 0.1 x the run's wall
TARGET_TRAJECTORIES_BYTES = 50e6    # output of the default suite: trajectory files
TARGET_REPORT_HTML_BYTES = 4e6      # ... report.html
TARGET_REPORT_MD_BYTES = 200e3      # ... report.md
TARGET_RSS_BYTES = 1e9              # peak RSS of a run of TARGET_RSS_STEPS steps
TARGET_RSS_STEPS = 10**7
# kept from issue 15 / 6
TARGET_MAP_SPEEDUP = 10.0           # maps: semi-implicit maps >= 10 x faster per step than mj_step
TARGET_OVERHEAD_RATIO = 1.3         # freebody's engine loop at most 1.3 x the bare loop

ENGINE_EQUIVALENT_MAPS = ("semi-implicit-explicit-gyro", "semi-implicit-implicit-gyro")
OTHER_FLOOR_MAPS = ("rk4", "symplectic-splitting", "implicit-midpoint", "rkmk4")

# --- what is run ----------------------------------------------------------------------------------------
# overhead: `freebody run CASE --engine <yardstick> --integrator Euler --dt 0.001 --duration 0.01`
# (one run of 10 steps) against the same over every bundled case and every integrator of the
# yardstick engine (one invocation of N runs)
OVERHEAD_DURATION_S = 0.01
OVERHEAD_INTEGRATOR = "Euler"
QUICK_OVERHEAD_CASES = ("dzhanibekov", "projectile", "quiz", "spinning_sphere")
# truth: the case of issue 29's figure (a constant body couple, 2 s at 1 ms: 2000 steps)
TRUTH_CASE = "body_torque_spinup"
# rss: a uniform rotation (isotropic inertia, no loads) stays bounded however long it runs
RSS_CASE = "spinning_sphere"
RSS_INTEGRATOR = "Euler"
QUICK_RSS_STEPS = 10**5
# sweep: issue 29's figure: 200 random bodies x 200 steps (2 s at 10 ms), MuJoCo Euler
SWEEP_COUNT = 200
QUICK_SWEEP_COUNT = 4
SWEEP_DT = 0.01
SWEEP_DURATION_S = 2.0
# suite with --quick: the default suite's runs of one case of 2-step runs, without MJX (not the
# default suite: shown, not judged)
QUICK_SUITE_CASES = ("quiz",)

PARTS = ("overhead", "compile", "maps", "truth", "sweep", "suite", "rss", "engines")


@dataclass(frozen=True)
class BenchConfig:
    """What one ``freebody bench`` measures.

    repeats : repeats of every in-process measurement and of the short commands (medians quoted).
    map_steps : steps of each reference-map call and of the yardstick loops it is compared with.
    engine_steps : steps of each engine loop (part "engines").
    overhead_cases : the cases of the N-run invocation (() = every bundled case).
    suite_cases : the suite's cases (() = the default suite, every bundled case).
    sweep_count : bodies of the timed sweeps.  rss_steps : steps of the RSS run (0: not measured).
    cold : the compile part and the suite's cold run get an empty numba cache (and JAX cache).
    parts : the parts measured (a subset of :data:`PARTS`).
    """

    quick: bool
    repeats: int
    map_steps: int
    engine_steps: int
    overhead_cases: tuple[str, ...]
    suite_cases: tuple[str, ...]
    sweep_count: int
    rss_steps: int
    cold: bool
    parts: tuple[str, ...]

    @classmethod
    def make(cls, quick: bool, repeats: int | None = None, rss_steps: int | None = None,
             cold: bool = False, parts: tuple[str, ...] | None = None) -> "BenchConfig":
        """The full bench, or with ``quick`` the cheap one (CI, tests): fewer repeats and steps,
        a slice of the suite, a 1e5-step RSS run, no cold compile unless ``cold``."""
        chosen = tuple(p for p in PARTS if p in (parts or PARTS))
        if quick:
            if not cold and parts is None:
                chosen = tuple(p for p in chosen if p != "compile")
            return cls(True, repeats or 3, 20_000, 500, QUICK_OVERHEAD_CASES, QUICK_SUITE_CASES,
                       QUICK_SWEEP_COUNT, QUICK_RSS_STEPS if rss_steps is None else rss_steps, cold,
                       chosen)
        return cls(False, repeats or 5, 200_000, 20_000, (), (), SWEEP_COUNT,
                   TARGET_RSS_STEPS if rss_steps is None else rss_steps, cold, chosen)
