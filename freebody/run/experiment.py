"""A run's experiment identity: what was simulated, so that ``freebody compare`` never judges a
different experiment (a shorter run, an edited case file, other values forced on the engine) as
better or worse.

``experiment(spec, settings)`` is the results.json ``experiment`` object of a run (schema 2)::

    {"fingerprint": "<16 hex>",        # sha256 of the fields below (sorted JSON), shortened
     "body": "<12 hex>",               # mass and inertia (exact float reprs)
     "initial": "<12 hex>",            # position, orientation, velocities at t = 0
     "gravity": "<12 hex>",
     "loads": "<12 hex>",              # every load's force, point, torques, start, steps, end
     "dt": float, "steps": int, "duration_s": float,   # what ran (duration_s = steps * dt)
     "settings": {key: value} | null}  # the values freebody set in the engine ("set" of
                                       # engine_settings, never the engine's own defaults, which
                                       # an upgrade may change); null when the run ended before
                                       # the engine was built (then not compared)

Two runs are the same experiment when every field both of them know is equal; of ``settings``,
the keys both sides have (an engine version without an option freebody sets elsewhere, such as
MuJoCo 3.1's missing auto-reset switch, is shown by :func:`setting_notes`, not a different
experiment).  Content fields are digests (a changed inertia shows as ``body``, not as numbers); dt,
steps, duration and settings are kept readable, so that a verdict can say ``steps 8000 -> 1000``.
"""
from __future__ import annotations

import hashlib
import json

import numpy as np

from ..reference_impl.problem import Problem

EXPERIMENT_FIELDS = ("body", "initial", "gravity", "loads", "dt", "steps", "duration_s", "settings")
DIGEST_HEX = 12  # hex digits of a field digest: 48 bits, collisions irrelevant at a few thousand runs
FINGERPRINT_HEX = 16


def _exact(x):
    """Numbers as exact text (float repr round-trips), arrays as nested lists of it."""
    if x is None:
        return None
    if isinstance(x, (bool, int, str)):
        return x
    a = np.asarray(x, dtype=float)
    return repr(float(a)) if a.ndim == 0 else [_exact(v) for v in a]


def _digest(obj) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:DIGEST_HEX]


def _content(problem: Problem) -> dict:
    b, s = problem.body, problem.initial
    loads = [{"force": _exact(ld.force), "point": _exact(ld.point), "body_point": _exact(ld.body_point),
              "torque": _exact(ld.torque), "body_torque": _exact(ld.body_torque), "start": _exact(ld.start),
              "steps": ld.steps, "end": _exact(ld.end)} for ld in problem.loads]
    return {
        "body": _digest({"mass": _exact(b.mass), "inertia": _exact(b.I_body)}),
        "initial": _digest({"position": _exact(s.position), "quaternion_wxyz": _exact(s.quaternion_wxyz),
                            "linear_velocity": _exact(s.linear_velocity),
                            "angular_velocity": _exact(s.angular_velocity)}),
        "gravity": _digest(_exact(problem.gravity)),
        "loads": _digest(loads),
    }


def experiment(problem: Problem, dt: float, steps: int, settings: dict | None = None) -> dict:
    """The ``experiment`` object of a run of ``problem`` at ``dt`` for ``steps`` steps; ``settings``
    is the adapter's ``settings`` ({key: {"default", "set"}}) or None when unknown."""
    fields = dict(_content(problem), dt=float(dt), steps=int(steps), duration_s=float(steps * dt),
                  settings=None if settings is None else {
                      k: _plain(v.get("set") if isinstance(v, dict) else v) for k, v in sorted(settings.items())})
    return {"fingerprint": hashlib.sha256(json.dumps(fields, sort_keys=True).encode()).hexdigest()[:FINGERPRINT_HEX],
            **fields}


def _plain(v):
    """A setting's value as JSON would store it (tuples as lists, numpy scalars as numbers)."""
    return json.loads(json.dumps(v, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def differences(base: dict | None, cur: dict | None) -> list[str]:
    """The fields in which two ``experiment`` objects differ, each as ``"name a -> b"`` (digests
    as ``"name changed"``); fields either side does not know (null or absent) are not compared.
    [] when they are the same experiment (or either is None)."""
    if not isinstance(base, dict) or not isinstance(cur, dict):
        return []
    out = []
    for f in EXPERIMENT_FIELDS:
        a, b = base.get(f), cur.get(f)
        if a is None or b is None or a == b:
            continue
        if f == "settings" and isinstance(a, dict) and isinstance(b, dict):
            out += [f"setting {k} {a[k]} -> {b[k]}" for k in sorted(set(a) & set(b)) if a[k] != b[k]]
        elif f == "settings":  # a schema-2 draft stored a digest: compare as a whole
            out.append("settings changed")
        elif f in ("dt", "steps", "duration_s"):
            out.append(f"{f} {a:g} -> {b:g}" if f != "steps" else f"steps {a} -> {b}")
        else:
            out.append(f"{f} changed")
    return out


def setting_notes(base: dict | None, cur: dict | None) -> list[str]:
    """The settings freebody set on one side only (an option one engine version lacks), each as
    ``"setting K only in baseline|current (= V)"``."""
    if not isinstance(base, dict) or not isinstance(cur, dict):
        return []
    a, b = base.get("settings"), cur.get("settings")
    if not isinstance(a, dict) or not isinstance(b, dict):
        return []
    return ([f"setting {k} only in baseline (= {a[k]})" for k in sorted(set(a) - set(b))]
            + [f"setting {k} only in current (= {b[k]})" for k in sorted(set(b) - set(a))])
