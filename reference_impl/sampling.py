"""How an engine's step samples the case's loads: the two sampling rules, by name.

A load's on/off timing is per step everywhere (``Load.step_range``: on for the steps
start <= t_k < stop).  What differs between engines is *where inside a step* the wrench of a
load that depends on the state (a body-frame couple R tau_b, a force at a body point (R b) x f,
a force at a world point (p - x) x f) is evaluated:

- ``per-stage``: from the state of every stage or substep the engine's scheme evaluates (RK4's
  four stages at (x_i, R(q_i))); a single-stage scheme (semi-implicit Euler) evaluates it once, at
  the step's start, which is the same thing.  The reference integrators do this.
- ``per-step``: the world wrench (force, torque about the COM) computed once from the state at
  the step's start (arms from x_k, R_k) and held over the whole step, every stage seeing the same
  world torque.  A multi-stage scheme driven this way is first order on a case whose loads turn
  with the body.

World couples and forces at the COM do not depend on the state: both rules give the same
experiment for them.  The engine-equivalent maps (:mod:`engine_maps`) have both variants; an
adapter declares its rule (``Adapter.load_sampling``) and identification uses the matching one.
"""
from __future__ import annotations

LOAD_SAMPLING_PER_STAGE = "per-stage"
LOAD_SAMPLING_PER_STEP = "per-step"

# rule -> one line for ``freebody conventions``, docs and reports
LOAD_SAMPLINGS: dict[str, str] = {
    LOAD_SAMPLING_PER_STAGE: "loads evaluated from the state of every stage or substep the "
                             "scheme evaluates (a body couple turns with each stage)",
    LOAD_SAMPLING_PER_STEP: "world wrench computed from the state at the step's start, held over "
                            "the whole step (every stage sees the same world torque)",
}


def check_load_sampling(value: str) -> str:
    """``value`` itself when it names a rule of :data:`LOAD_SAMPLINGS`, else ValueError."""
    if value not in LOAD_SAMPLINGS:
        raise ValueError(f"unknown load sampling {value!r}; known: {', '.join(LOAD_SAMPLINGS)}")
    return value
