"""``freebody bench``: how fast freebody is on the paths users take, next to the engines it drives,
each target of issue 29 checked in the same run (PASS, MISS, or n/a with the reason).

Everything is measured side by side in one run, each figure the median over interleaved repeats
(the machine may be shared and noisy: a drift of its load hits both sides of a ratio alike), CPU
time for commands (user + system of the command and its worker processes) and in-process work,
wall time where the target is a wall time.  The parts (``--part`` selects some):

- ``overhead`` (:mod:`.overhead`): a one-run ``freebody run`` invocation (10 MuJoCo Euler steps,
  imports included) and one invocation of N such runs (every bundled case x every MuJoCo
  integrator): the marginal run = (N-run CPU - one-run CPU) / (N - 1).  Targets <= 5 ms, <= 1.2 s.
- ``compile`` (:mod:`.overhead`): the CPU of the quick start's compilations, a short run of every
  case on the reference engine and MuJoCo with an empty ``NUMBA_CACHE_DIR`` minus the same warm.
  Target <= 8 s.  Not with ``--quick`` unless ``--cold``.
- ``maps`` (:mod:`.maps`): each reference map per step against MuJoCo's ``mj_step`` in Python
  (>= 10x, issue 15), ``mujoco.rollout`` (shown) and its floor, a flat loop of the same arithmetic
  (``reference_impl/floors.py``: <= 1.5x semi-implicit, <= 3x rk4/splitting/midpoint/rkmk4).
- ``truth`` (:mod:`.truth`): the numerical truth against scipy's DOP853 with a numba right-hand
  side at the same tolerances (<= 3x).
- ``sweep`` (:mod:`.sweep`): ``freebody sweep`` of 200 bodies x 200 steps on MuJoCo Euler against
  ``mujoco.rollout`` of the same bodies (>= 1/10 of its body-steps/s), ``--jobs 2`` vs 1 (>= 1.6x).
- ``suite`` (:mod:`.suite`): the default suite cold and warm, ``freebody report`` of it (<= 0.1x
  the run), its output (<= 50 MB trajectories, 4 MB report.html, 200 KB report.md), the suite
  without MJX with one worker against its runs' engine stepping (<= 4x), MJX's stepping against
  MuJoCo's in the warm suite (<= 2x).
- ``rss`` (:mod:`.rss`): peak RSS of a 10^7-step run (<= 1 GB).
- ``engines`` (:mod:`.maps`): each engine's bare loop vs ``adapter.simulate`` (<= 1.3x, issue 6).

The result is one JSON document (schema :data:`SCHEMA_VERSION`; schema 3 documents are read by
:func:`load_bench`) and a text summary (:func:`format_text`): the table of checks first.
"""
from __future__ import annotations

from .checks import checks
from .config import PARTS, BenchConfig
from .core import Check, Child, folder_bytes, make_check, meets, run_child
from .document import READABLE_SCHEMAS, SCHEMA_VERSION, load_bench, run_bench, update_to_4
from .text import format_checks, format_text

__all__ = ["BenchConfig", "Check", "Child", "PARTS", "READABLE_SCHEMAS", "SCHEMA_VERSION", "checks",
           "folder_bytes", "format_checks", "format_text", "load_bench", "make_check", "meets",
           "run_bench", "run_child", "update_to_4"]
