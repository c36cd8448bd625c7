"""Case files: TOML under ``cases/`` (or a user's own path) parsed and validated into a Problem.

Every error is an :class:`InputError` whose one-line message names the file, the key and the
reason.  The format (units are normative)::

    name = "example"
    description = "What this case shows, in one sentence."
    duration = 10.0                # s; or duration_steps = 2 (a number of steps at every dt)
    dt = [0.01, 0.001]             # s, default time steps; steps = round(duration / dt)
    [body]
    mass = 1.0                     # kg
    inertia = [[1,0,0],[0,2,0],[0,0,3]]   # kg m^2, about the COM, body frame
    # or: shape = "box" | "sphere" | "cylinder" | "capsule" | "ellipsoid" | "cone", size = [...] (m),
    # or: mesh = "part.obj" (closed OBJ/STL, relative to this file); with mass or density (kg/m^3)
    [initial]
    position = [0, 0, 0]           # m, COM, world
    orientation = [1, 0, 0, 0]     # (w, x, y, z), body -> world
    linear_velocity = [0, 0, 0]    # m/s, COM, world
    angular_velocity = [0, 5, 0]   # rad/s, world
    [world]
    gravity = [0, 0, 0]            # m/s^2
    [[loads]]                      # zero or more
    force = [1, 0, 0]              # N, world; at point (world) or body_point (body) or the COM
    torque = [0, 0, 1]             # N m, world couple;  body_torque: N m, body-frame couple
    start = 0.0                    # s;  steps = N or end = <s>; neither: to the end
"""
from __future__ import annotations

import math
import tomllib
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from .. import tolerances as tol
from ..errors import InputError
from ..reference_impl import massprops
from ..reference_impl.problem import Body, InitialState, Load, Problem

TOP_KEYS = {"name", "description", "duration", "duration_steps", "dt", "body", "initial", "world", "loads"}
BODY_KEYS = {"mass", "inertia", "shape", "size", "density", "mesh"}
INITIAL_KEYS = {"position", "orientation", "linear_velocity", "angular_velocity"}
WORLD_KEYS = {"gravity"}
LOAD_KEYS = {"force", "point", "body_point", "torque", "body_torque", "start", "steps", "end"}


class CaseWarning(UserWarning):
    """A case value that was accepted after a correction (e.g. a normalised quaternion)."""


# --- finding cases ----------------------------------------------------------------------------

def bundled_case_paths() -> dict[str, Path]:
    """Bundled case name -> path, sorted by name (the cases ship in the package ``freebody.cases``)."""
    root = resources.files("freebody.cases")
    out = {}
    for entry in root.iterdir():
        if entry.name.endswith(".toml"):
            out[entry.name[:-5]] = Path(str(entry))
    return dict(sorted(out.items()))


def resolve_case(name_or_path: str) -> Path:
    """A bundled case name, or a path to a TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists() or "/" in name_or_path:
        if not p.is_file():
            raise InputError(f"{name_or_path}: case file not found")
        return p
    cases = bundled_case_paths()
    if name_or_path not in cases:
        raise InputError(f"{name_or_path}: unknown case; known cases: {', '.join(cases)} "
                         "(or give a path to a .toml file)")
    return cases[name_or_path]


def load_case(name_or_path: str | Path) -> Problem:
    """Parse and validate a case (bundled name or path) into a :class:`Problem`."""
    path = resolve_case(str(name_or_path))
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise InputError(f"{path}: cannot read: {e.strerror}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{path}: invalid TOML: {e}") from None
    return parse_case(data, str(path))


# --- validation helpers -----------------------------------------------------------------------

class _Ctx:
    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, reason: str):
        key = "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in key)
        reason = " ".join(reason.splitlines())
        raise InputError(f"{self.source}: {key}: {reason}")

    def keys(self, table, allowed: set[str], where: str, required: set[str] = frozenset()):
        if not isinstance(table, dict):
            self.fail(where or "(top level)", "must be a table")
        for k in table:
            if k not in allowed:
                hint = _closest(k, allowed)
                self.fail(f"{where}.{k}" if where else k,
                          "unknown key" + (f" (did you mean {hint!r}?)" if hint else "")
                          + f"; allowed: {', '.join(sorted(allowed))}")
        for k in sorted(required):
            if k not in table:
                self.fail(f"{where}.{k}" if where else k, "missing required key")

    def number(self, value, key: str, positive: bool = False, nonneg: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"must be a number, got {value!r}")
        x = float(value)
        if not math.isfinite(x):
            self.fail(key, f"must be finite, got {value!r}")
        if positive and x <= 0:
            self.fail(key, f"must be > 0, got {value!r}")
        if nonneg and x < 0:
            self.fail(key, f"must be >= 0, got {value!r}")
        return x

    def integer(self, value, key: str, minimum: int = 1) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be an integer, got {value!r}")
        if value < minimum:
            self.fail(key, f"must be >= {minimum}, got {value!r}")
        return int(value)

    def vector(self, value, key: str, n: int) -> np.ndarray:
        if not isinstance(value, list) or len(value) != n:
            self.fail(key, f"must be a list of {n} numbers, got {value!r}")
        return np.array([self.number(v, f"{key}[{i}]") for i, v in enumerate(value)])

    def matrix(self, value, key: str) -> np.ndarray:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(r, list) and len(r) == 3 for r in value)):
            self.fail(key, f"must be a 3x3 list of lists of numbers, got {value!r}")
        return np.array([[self.number(v, f"{key}[{i}][{j}]") for j, v in enumerate(r)]
                         for i, r in enumerate(value)])


def _closest(word: str, options: set[str]) -> str | None:
    import difflib

    m = difflib.get_close_matches(word, sorted(options), n=1, cutoff=0.6)
    return m[0] if m else None


def validate_inertia(I: np.ndarray, fail) -> None:
    """Symmetric, positive definite, principal moments satisfying the triangle inequality."""
    scale = float(np.max(np.abs(I)))
    if scale == 0 or np.max(np.abs(I - I.T)) > tol.SYMMETRY_RTOL * scale:
        fail("not symmetric" if scale else "is zero")
    ev = np.linalg.eigvalsh(0.5 * (I + I.T))
    if ev[0] <= 0:
        fail(f"not positive definite (principal moments {_fmt(ev)})")
    if ev[0] + ev[1] < ev[2] * (1 - tol.TRIANGLE_INEQUALITY_RTOL):
        fail(f"principal moments {_fmt(ev)} violate the triangle inequality I1 + I2 >= I3: "
             "no rigid body has them")


def _fmt(a) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in a) + ")"


# --- the parser -------------------------------------------------------------------------------

def parse_case(data: dict, source: str = "<case>") -> Problem:
    """Validate a case's TOML data (as from ``tomllib``) into a :class:`Problem`."""
    c = _Ctx(source)
    c.keys(data, TOP_KEYS, "", required={"name", "description", "dt", "body", "initial"})
    name = data["name"]
    if not isinstance(name, str) or not name.strip():
        c.fail("name", "must be a non-empty string")
    if not isinstance(data["description"], str):
        c.fail("description", "must be a string")

    dts_raw = data["dt"]
    dts_list = dts_raw if isinstance(dts_raw, list) else [dts_raw]
    if not dts_list:
        c.fail("dt", "must list at least one time step")
    dts = tuple(c.number(d, "dt", positive=True) for d in dts_list)

    if ("duration" in data) == ("duration_steps" in data):
        c.fail("duration", "give exactly one of duration (s) and duration_steps")
    duration = duration_steps = None
    if "duration" in data:
        duration = c.number(data["duration"], "duration", positive=True)
        for d in dts:
            if duration < d * (1 - tol.DURATION_VS_DT_RTOL):
                c.fail("duration", f"{duration} s is shorter than dt = {d} s")
    else:
        duration_steps = c.integer(data["duration_steps"], "duration_steps")

    body = _parse_body(c, data["body"])
    initial = _parse_initial(c, data["initial"])
    gravity = np.zeros(3)
    if "world" in data:
        c.keys(data["world"], WORLD_KEYS, "world", required={"gravity"})
        gravity = c.vector(data["world"]["gravity"], "world.gravity", 3)

    loads_raw = data.get("loads", [])
    if not isinstance(loads_raw, list):
        c.fail("loads", "must be an array of tables ([[loads]])")
    loads = tuple(_parse_load(c, ld, i) for i, ld in enumerate(loads_raw))
    return Problem(name=name, description=data["description"], body=body, initial=initial,
                   gravity=gravity, loads=loads, duration=duration, duration_steps=duration_steps,
                   dts=dts)


def _parse_body(c: _Ctx, b) -> Body:
    c.keys(b, BODY_KEYS, "body")
    if "mesh" in b:
        return _parse_mesh_body(c, b)
    has_inertia, has_shape = "inertia" in b, "shape" in b
    if has_inertia == has_shape:
        c.fail("body.inertia", "give exactly one of inertia, shape and mesh")
    if has_inertia:
        for k in ("size", "density"):
            if k in b:
                c.fail(f"body.{k}", "only with shape (an inertia is given)")
        if "mass" not in b:
            c.fail("body.mass", "missing required key")
        mass = c.number(b["mass"], "body.mass", positive=True)
        I = c.matrix(b["inertia"], "body.inertia")
    else:
        shape = b["shape"]
        if shape not in massprops.SHAPES:
            c.fail("body.shape", f"unknown shape {shape!r}; known: {', '.join(massprops.SHAPES)}")
        if "size" not in b:
            c.fail("body.size", "missing required key (with shape)")
        size = c.vector(b["size"], "body.size", massprops.SHAPES[shape])
        if np.any(size <= 0):
            c.fail("body.size", f"must be > 0, got {b['size']!r}")
        if ("mass" in b) == ("density" in b):
            c.fail("body.mass", "give exactly one of mass and density (with shape)")
        if "mass" in b:
            mass = c.number(b["mass"], "body.mass", positive=True)
        else:
            mass = c.number(b["density"], "body.density", positive=True) * massprops.volume(shape, size)
        I = massprops.inertia(shape, size, mass)
    validate_inertia(I, lambda why: c.fail("body.inertia", why))
    return Body(mass=mass, I_body=0.5 * (I + I.T))


def _parse_mesh_body(c: _Ctx, b) -> Body:
    """``mesh = "path.obj"`` (OBJ or STL, relative to the case file's folder) with mass or density.

    Mass, COM and inertia come from exact polyhedral integration (docs/mass-properties.md).  The
    body origin is the mesh's COM: the mesh's axes are the body axes, and the case's
    initial.position is where that COM starts (world).
    """
    from .meshfile import body_from_mesh
    from ..reference_impl.mesh import MeshError

    for k in ("inertia", "shape", "size"):
        if k in b:
            c.fail(f"body.{k}", "give exactly one of inertia, shape and mesh (a mesh is given)")
    if not isinstance(b["mesh"], str) or not b["mesh"].strip():
        c.fail("body.mesh", f"must be a path to an .obj or .stl file, got {b['mesh']!r}")
    if ("mass" in b) == ("density" in b):
        c.fail("body.mass", "give exactly one of mass and density (with mesh)")
    key = "mass" if "mass" in b else "density"
    value = c.number(b[key], f"body.{key}", positive=True)
    path = Path(c.source).parent / b["mesh"]
    try:
        _, props = body_from_mesh(path, **{key: value})
    except MeshError as e:
        c.fail("body.mesh", f"{path}: {e}")
    validate_inertia(props.inertia, lambda why: c.fail("body.mesh", f"{path}: inertia {why}"))
    return Body(mass=props.mass, I_body=props.inertia)


def _parse_initial(c: _Ctx, t) -> InitialState:
    c.keys(t, INITIAL_KEYS, "initial", required=INITIAL_KEYS)
    q = c.vector(t["orientation"], "initial.orientation", 4)
    n = float(np.linalg.norm(q))
    if n == 0:
        c.fail("initial.orientation", "is the zero quaternion (w, x, y, z); identity is [1, 0, 0, 0]")
    if abs(n - 1) > tol.UNIT_QUATERNION_RTOL:
        warnings.warn(f"{c.source}: initial.orientation: |q| = {n:.6g}, normalised to a unit "
                      "quaternion", CaseWarning, stacklevel=2)
    return InitialState(position=c.vector(t["position"], "initial.position", 3), quaternion_wxyz=q / n,
                        linear_velocity=c.vector(t["linear_velocity"], "initial.linear_velocity", 3),
                        angular_velocity=c.vector(t["angular_velocity"], "initial.angular_velocity", 3))


def _parse_load(c: _Ctx, ld, i: int) -> Load:
    where = f"loads[{i}]"
    c.keys(ld, LOAD_KEYS, where)
    if not any(k in ld for k in ("force", "torque", "body_torque")):
        c.fail(where, "a load needs force, torque or body_torque")
    if "point" in ld and "body_point" in ld:
        c.fail(f"{where}.point", "give at most one of point and body_point")
    if ("point" in ld or "body_point" in ld) and "force" not in ld:
        c.fail(f"{where}.force", "a point of application needs a force")
    if "steps" in ld and "end" in ld:
        c.fail(f"{where}.steps", "give at most one of steps and end")
    kw = {}
    for k in ("force", "point", "body_point", "torque", "body_torque"):
        if k in ld:
            kw[k] = c.vector(ld[k], f"{where}.{k}", 3)
    start = c.number(ld.get("start", 0.0), f"{where}.start", nonneg=True)
    if "steps" in ld:
        kw["steps"] = c.integer(ld["steps"], f"{where}.steps")
    if "end" in ld:
        end = c.number(ld["end"], f"{where}.end")
        if end <= start:
            c.fail(f"{where}.end", f"must be after start ({start} s), got {end}")
        kw["end"] = end
    return Load(start=start, **kw)
