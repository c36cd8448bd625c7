"""Case files: TOML under ``cases/`` (or a user's own path) parsed and validated into a Problem.

Every error is an :class:`InputError` whose one-line message names the file, the key and the
reason.  The format (units are normative; docs/case-files.md has every key in a table, and
``freebody new-case`` prints a commented template)::

    name = "example"               # required
    description = "What this case shows, in one sentence."   # optional, default ""
    duration = 10.0                # s; or duration_steps = 2 (a number of steps at every dt)
    dt = [0.01, 0.001]             # s, default time steps; steps = round(duration / dt)
    [body]                         # required
    mass = 1.0                     # kg
    inertia = [[1,0,0],[0,2,0],[0,0,3]]   # kg m^2, about the COM, body frame
    # or: shape = "box" | "sphere" | "cylinder" | "capsule" | "ellipsoid" | "cone", size = [...] (m),
    # or: mesh = "part.obj" (closed OBJ/STL, relative to this file); with mass or density (kg/m^3)
    [initial]                      # optional: every key defaults (DEFAULTS): at rest at the origin
    position = [0, 0, 0]           # m, COM, world
    orientation = [1, 0, 0, 0]     # (w, x, y, z), body -> world
    linear_velocity = [0, 0, 0]    # m/s, COM, world
    angular_velocity = [0, 5, 0]   # rad/s, world
    [world]                        # optional: no [world] is no gravity
    gravity = [0, 0, 0]            # m/s^2
    [[loads]]                      # zero or more
    force = [1, 0, 0]              # N, world; at point (world) or body_point (body) or the COM
    torque = [0, 0, 1]             # N m, world couple;  body_torque: N m, body-frame couple
    start = 0.0                    # s;  steps = N or end = <s>; neither: to the end

``dt`` and ``duration`` (or ``duration_steps``) may be left out of a file when the command line
gives ``--dt`` and ``--duration``: the Problem then has ``dts == ()`` and ``duration is None``, and
:func:`check_run_settings` (called where the runs are expanded) says which is missing.
"""
from __future__ import annotations

import errno
import math
import os
import tomllib
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from .. import tolerances as tol
from ..errors import InputError, abbreviated, printable
from ..reference_impl import massprops
from ..reference_impl.problem import Body, InitialState, Load, Problem

TOP_KEYS = {"name", "description", "duration", "duration_steps", "dt", "body", "initial", "world", "loads"}
BODY_KEYS = {"mass", "inertia", "shape", "size", "density", "mesh"}
INITIAL_KEYS = {"position", "orientation", "linear_velocity", "angular_velocity"}
WORLD_KEYS = {"gravity"}
LOAD_KEYS = {"force", "point", "body_point", "torque", "body_torque", "start", "steps", "end"}
SECTIONS = {"body": BODY_KEYS, "initial": INITIAL_KEYS, "world": WORLD_KEYS, "loads": LOAD_KEYS}
"""The top-level keys that are tables (``[[loads]]``: an array of tables) -> their keys."""
REQUIRED_TOP_KEYS = frozenset({"name", "body"})
"""Required whatever the command line says; ``dt`` and a duration are required to *run* a case,
from the file or from ``--dt`` / ``--duration`` (:func:`check_run_settings`)."""
DEFAULTS = {
    "description": "",
    "initial.position": [0.0, 0.0, 0.0],
    "initial.orientation": [1.0, 0.0, 0.0, 0.0],
    "initial.linear_velocity": [0.0, 0.0, 0.0],
    "initial.angular_velocity": [0.0, 0.0, 0.0],
    "world.gravity": [0.0, 0.0, 0.0],
}
"""Optional keys (dotted: section.key) -> the TOML value a case that leaves them out gets: a body
at rest at the origin, unrotated, without gravity, without a description.  :func:`defaulted_keys`
lists the ones a case used.  (A load's ``start`` defaults to 0 s too: a load without it acts from
the first step; it is not listed.)"""
# A case's name names its runs in tables, progress lines and file names: at most this many
# characters, printable (no control characters or terminal escape sequences).
CASE_NAME_MAX_CHARS = 100
# Time steps one case may list: each is a run per engine, integrator and precision, so 1000 is
# already some 10^5 runs, beyond any convergence study (tens of steps); a longer list (a file of
# two million, 12 MB) is refused before it is parsed number by number, instead of working for minutes.
MAX_TIME_STEPS_PER_CASE = 1000


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
    """A bundled case name, or a path to a TOML file.  A path that exists is returned whatever it
    is (a folder, a FIFO, a device): reading it says what it is instead of "not found"."""
    p = Path(name_or_path)
    shown = printable(name_or_path)
    exists = _exists(p, shown)
    if p.suffix == ".toml" or exists or "/" in name_or_path:
        if not exists:
            raise InputError(f"{shown}: case file not found")
        return p
    cases = bundled_case_paths()
    if name_or_path not in cases:
        raise InputError(f"{shown}: unknown case; known cases: {', '.join(cases)} "
                         "(or give a path to a .toml file)")
    return cases[name_or_path]


def _exists(p: Path, shown: str) -> bool:
    """Whether anything is at ``p`` (following symbolic links); InputError for a path the system
    cannot even look up (too long, a NUL character)."""
    try:
        os.stat(p)
        return True
    except (FileNotFoundError, NotADirectoryError):
        return False
    except ValueError:  # an embedded NUL character
        raise InputError(f"{shown}: not a valid path (it contains a NUL character)") from None
    except OSError as e:
        if e.errno == errno.ELOOP:
            return False
        if e.errno == errno.ENAMETOOLONG:
            raise InputError(f"{shown[:60]}...: path too long for the file system") from None
        return True  # e.g. no permission to look: reading it says why


def load_case(name_or_path: str | Path) -> Problem:
    """Parse and validate a case (bundled name or path) into a :class:`Problem`."""
    path = resolve_case(str(name_or_path))
    return parse_case(_read_toml(path), str(path))


def defaulted_keys(case: str | Path | dict) -> list[str]:
    """The optional keys (dotted, as in :data:`DEFAULTS`) that a case leaves out and so gets by
    default, in the order of DEFAULTS; e.g. ``["description", "world.gravity"]`` for a file
    without a description and without ``[world]`` (no gravity).

    case : a bundled case name or a path (read again; InputError as :func:`load_case`), or the
        case's TOML data (a dict, as from ``tomllib``).  Meant for a case that loads.
    """
    data = case if isinstance(case, dict) else _read_toml(resolve_case(str(case)))
    out = []
    for dotted in DEFAULTS:
        section, _, key = dotted.rpartition(".")
        table = data.get(section, {}) if section else data
        if not isinstance(table, dict) or key not in table:
            out.append(dotted)
    return out


def _read_toml(path: Path) -> dict:
    """The TOML data of the case file at ``path``; InputError naming the file if it is not one."""
    from ..results.io import read_regular_file

    where = printable(path)
    raw = read_regular_file(path, tol.CASE_FILE_MAX_BYTES, where)  # a regular file, size-limited
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise InputError(f"{where}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{where}: invalid TOML: {e}") from None
    except (ValueError, RecursionError) as e:  # e.g. an integer of more than 4300 digits; deep nesting
        why = "nested too deeply" if isinstance(e, RecursionError) else str(e).split(";")[0]
        raise InputError(f"{where}: invalid TOML: {why}") from None
    return data


def check_step_count(duration: float, dt: float, fail) -> int:
    """The number of steps, round(duration / dt) (at least 1), of a run; ``fail(reason)`` (which
    raises) when it exceeds :data:`~freebody.tolerances.MAX_STEPS_PER_RUN` or cannot be computed."""
    count = duration / dt  # inf when it overflows (dt = 1e-320, duration = 1e308)
    if not count <= tol.MAX_STEPS_PER_RUN + 0.5:
        shown = f"{count:.3g}" if math.isfinite(count) else "more than 1.8e308"
        fail(f"{duration!r} s at dt = {dt!r} s is {shown} steps; a run has at most "
             f"{tol.MAX_STEPS_PER_RUN:.0e} steps (MAX_STEPS_PER_RUN): use a larger dt or a shorter duration")
    return max(1, int(round(count)))


def check_run_lengths(problems, dts=None, duration=None) -> None:
    """Check the time steps and durations given on the command line (``--dt``, ``--duration``;
    None: the cases' own, checked when their files were read): InputError unless every run of
    every problem has at most MAX_STEPS_PER_RUN steps and a dt of at least INPUT_POSITIVE_MIN."""
    if not dts and duration is None:
        return
    option = "--duration" if duration is not None else "--dt"
    for pb in problems:
        def fail(why, pb=pb):
            raise InputError(f"{option}: case {printable(pb.name)}: {why}")

        for d in dts or pb.dts:
            total = duration if duration is not None else pb.duration
            if total is not None:
                check_step_count(total, d, fail)
            if d < tol.INPUT_POSITIVE_MIN:
                raise InputError(f"--dt: must be at least {tol.INPUT_POSITIVE_MIN:g} s (smaller steps are too "
                                 f"small to compute with in float64), got {d!r}")


def check_run_settings(problems, dts=None, duration=None, sources=None) -> None:
    """InputError when a problem has no time step (no ``dt`` in its file) and ``dts`` (``--dt``)
    is empty, or no duration (neither ``duration`` nor ``duration_steps`` in its file) and
    ``duration`` (``--duration``) is None.  ``sources``: where each problem came from (the paths or
    names given on the command line), to name the file; else the case is named."""
    for i, pb in enumerate(problems):
        where = printable(sources[i]) if sources is not None else f"case {printable(pb.name)!r}"
        if not dts and not pb.dts:
            raise InputError(f"{where}: dt: missing; give dt = [...] (s, the time steps) in the case file "
                             "or --dt on the command line")
        if duration is None and pb.duration is None and pb.duration_steps is None:
            raise InputError(f"{where}: duration: missing; give duration = ... (s) or duration_steps = ... "
                             "in the case file or --duration on the command line")


# --- validation helpers -----------------------------------------------------------------------

class _Ctx:
    def __init__(self, source: str):
        self.source = source

    def fail(self, key: str, reason: str):
        raise InputError(f"{printable(self.source)}: {printable(key)}: {printable(' '.join(reason.splitlines()))}")

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

    def number(self, value, key: str, positive: bool = False, nonneg: bool = False,
               tiny_ok: bool = False) -> float:
        """A finite number of magnitude at most INPUT_MAGNITUDE_MAX; with ``positive`` > 0 and (unless
        ``tiny_ok``) at least INPUT_POSITIVE_MIN (freebody.tolerances)."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"must be a number, got {abbreviated(value)}")
        try:
            x = float(value)
        except OverflowError:  # an integer beyond float64's range
            x = math.inf if value > 0 else -math.inf
        if math.isnan(x) or (math.isinf(x) and isinstance(value, float)):
            self.fail(key, f"must be finite, got {value!r}")
        if abs(x) > tol.INPUT_MAGNITUDE_MAX:
            self.fail(key, f"must be at most {tol.INPUT_MAGNITUDE_MAX:g} in magnitude (squares of larger "
                           f"numbers overflow float64), got {abbreviated(value)}")
        if positive and x <= 0:
            self.fail(key, f"must be > 0, got {value!r}")
        if positive and not tiny_ok and x < tol.INPUT_POSITIVE_MIN:
            self.fail(key, f"must be at least {tol.INPUT_POSITIVE_MIN:g} (smaller numbers are too small to "
                           f"compute with in float64: their squares vanish), got {value!r}")
        if nonneg and x < 0:
            self.fail(key, f"must be >= 0, got {value!r}")
        return x

    def integer(self, value, key: str, minimum: int = 1, maximum: int | None = None,
                why_maximum: str = "") -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"must be an integer, got {abbreviated(value)}")
        if value < minimum:
            self.fail(key, f"must be >= {minimum}, got {abbreviated(value)}")
        if maximum is not None and value > maximum:
            self.fail(key, f"must be at most {maximum}{why_maximum}, got {abbreviated(value)}")
        return int(value)

    def vector(self, value, key: str, n: int, **number_options) -> np.ndarray:
        if not isinstance(value, list) or len(value) != n:
            self.fail(key, f"must be a list of {n} numbers, got {abbreviated(value)}")
        return np.array([self.number(v, f"{key}[{i}]", **number_options) for i, v in enumerate(value)])

    def matrix(self, value, key: str) -> np.ndarray:
        if (not isinstance(value, list) or len(value) != 3
                or not all(isinstance(r, list) and len(r) == 3 for r in value)):
            self.fail(key, f"must be a 3x3 list of lists of numbers, got {abbreviated(value)}")
        return np.array([[self.number(v, f"{key}[{i}][{j}]") for j, v in enumerate(r)]
                         for i, r in enumerate(value)])


def _closest(word: str, options: set[str]) -> str | None:
    import difflib

    m = difflib.get_close_matches(word, sorted(options), n=1, cutoff=0.6)
    return m[0] if m else None


def validate_inertia(I: np.ndarray, fail) -> None:
    """Finite, symmetric, positive definite, principal moments from INPUT_POSITIVE_MIN to
    INPUT_MAGNITUDE_MAX (freebody.tolerances) satisfying the triangle inequality."""
    if not np.all(np.isfinite(I)):
        fail("is not finite (it overflows float64)")
    scale = float(np.max(np.abs(I)))
    if scale == 0 or np.max(np.abs(I - I.T)) > tol.SYMMETRY_RTOL * scale:
        fail("not symmetric" if scale else "is zero")
    # eigenvalues of I / scale, then scaled back: LAPACK squares the entries of what it is given
    ev = scale * np.linalg.eigvalsh(0.5 * (I + I.T) / scale)
    if ev[0] <= 0:
        fail(f"not positive definite (principal moments {_fmt(ev)})")
    if ev[2] > tol.INPUT_MAGNITUDE_MAX or ev[0] < tol.INPUT_POSITIVE_MIN:
        fail(f"principal moments {_fmt(ev)} kg m^2 are not all from {tol.INPUT_POSITIVE_MIN:g} to "
             f"{tol.INPUT_MAGNITUDE_MAX:g}: too {'large' if ev[2] > tol.INPUT_MAGNITUDE_MAX else 'small'} "
             "to compute with in float64")
    if ev[0] + ev[1] < ev[2] * (1 - tol.TRIANGLE_INEQUALITY_RTOL):
        fail(f"principal moments {_fmt(ev)} violate the triangle inequality I1 + I2 >= I3: "
             "no rigid body has them")


def validate_mass(mass: float, fail, what: str = "mass") -> None:
    """``fail(reason)`` unless a (computed) mass, kg, is from INPUT_POSITIVE_MIN to INPUT_MAGNITUDE_MAX."""
    if not (tol.INPUT_POSITIVE_MIN <= mass <= tol.INPUT_MAGNITUDE_MAX):
        fail(f"{what} {mass:.6g} kg is not from {tol.INPUT_POSITIVE_MIN:g} to {tol.INPUT_MAGNITUDE_MAX:g}: "
             "too large or too small to compute with in float64")


def validate_volume(volume: float, fail) -> None:
    """``fail(reason)`` unless a computed volume, m^3, is from INPUT_POSITIVE_MIN to INPUT_MAGNITUDE_MAX."""
    if not (tol.INPUT_POSITIVE_MIN <= volume <= tol.INPUT_MAGNITUDE_MAX):
        fail(f"its volume {volume:.6g} m^3 is not from {tol.INPUT_POSITIVE_MIN:g} to "
             f"{tol.INPUT_MAGNITUDE_MAX:g}: too large or too small to compute with in float64")


def _fmt(a) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in a) + ")"


# --- templates (freebody new-case) -------------------------------------------------------------

def case_template(name: str = "my-case", minimal: bool = False) -> str:
    """A case file's text, valid as is (:func:`parse_case` accepts it; ``freebody run`` runs it).

    The full template lists every key of every section, each with whether it is required, its
    default (:data:`DEFAULTS`), unit and frame; the keys that are alternatives (shape, mesh, ...)
    and the [[loads]] table are commented out.  ``minimal``: the five-line file of
    docs/case-files.md, a body spinning about its middle axis.  InputError (from the parser, source
    ``new-case``) for a name that no case may have."""
    rows = _MINIMAL if minimal else _template_rows()
    column = _COMMENT_COLUMN if not minimal else max(len(r[0]) for r in rows) + 1
    data = tomllib.loads(_render(rows, "NAME", column))
    data["name"] = name
    parse_case(data, "new-case")  # the name's errors (one line), and the template's own
    return _render(rows, name, column)


def _render(rows, name: str, column: int) -> str:
    """The template's text: rows of (assignment, comment), comments aligned after the assignments
    shorter than ``column``; plain lines as they are."""
    rows = [(f"name = {_toml(name)}", r[1]) if isinstance(r, tuple) and r[0] == "name = NAME" else r
            for r in rows]
    width = max(len(r[0]) for r in rows if isinstance(r, tuple) and len(r[0]) < column)
    return "\n".join(r if isinstance(r, str) else f"{r[0]:<{width}}  # {r[1]}" for r in rows) + "\n"


_COMMENT_COLUMN = 40  # assignments longer than this do not push the other comments right

_MINIMAL = [
    ("name = NAME", "required"),
    ("dt = 0.01", "s, the time step"),
    ("duration = 10.0", "s, simulated time"),
    ("body = { mass = 1.0, inertia = [[1, 0, 0], [0, 2, 0], [0, 0, 3]] }", "kg; kg m^2, about the COM, body frame"),
    ("initial = { angular_velocity = [0.01, 5, 0] }", "rad/s, world frame"),
]


def _template_rows() -> list:
    """The full template: (assignment, comment) rows and plain lines."""
    d = {k: _toml(v) for k, v in DEFAULTS.items()}
    return [
        "# A freebody case: one free rigid body (no contacts, no joints) in constant gravity, with",
        "# optional external loads.  Every key is listed: the optional ones show their default, the",
        "# alternatives are commented out.  SI units.  Frames: \"world\" is fixed; \"body\" is attached to",
        "# the body, its origin at the centre of mass (COM).  Every key: docs/case-files.md.",
        "",
        ("name = NAME", "required: names the runs in tables and files (at most 100 printable characters)"),
        (f"description = {d['description']}", "optional, default \"\": one sentence, shown in reports"),
        ("dt = [0.01]", "s, the time steps (a number or a list; one run each); or --dt on the command line"),
        ("duration = 10.0", "s, simulated time, steps = round(duration / dt); or --duration on the command line"),
        ("# duration_steps = 1000", "instead of duration: this many steps at every dt"),
        "",
        ("[body]", "required: mass and inertia, or a shape, or a mesh"),
        ("mass = 1.0", "kg; with shape or mesh: mass or density"),
        ("inertia = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]", "kg m^2, about the COM, body frame"),
        "# Instead of inertia, a solid of uniform density with its COM at the body origin:",
        ('# shape = "box"', " | ".join(massprops.SHAPES)),
        ("# size = [0.1, 0.2, 0.3]", "m, body frame, by shape:"),
        *(f"#     {shape:<9}  {doc}" for shape, doc in massprops.SIZE_DOC.items()),
        ("# density = 1000.0", "kg/m^3, instead of mass (with shape or mesh)"),
        "# or a closed triangle mesh (the body origin is its COM, the body axes are the mesh's axes):",
        ('# mesh = "part.obj"', "an OBJ or STL file, coordinates in m, path relative to this file"),
        "",
        ("[initial]", "optional: the state at t = 0"),
        (f"position = {d['initial.position']}", f"m, COM, world frame; default {d['initial.position']}"),
        (f"orientation = {d['initial.orientation']}",
         f"unit quaternion (w, x, y, z), body -> world; default {d['initial.orientation']} (identity)"),
        (f"linear_velocity = {d['initial.linear_velocity']}",
         f"m/s, COM, world frame; default {d['initial.linear_velocity']}"),
        ("angular_velocity = [0.01, 5.0, 0.0]",
         f"rad/s, world frame; default {d['initial.angular_velocity']} (at rest)"),
        "",
        ("[world]", "optional"),
        (f"gravity = {d['world.gravity']}",
         f"m/s^2, world frame; default {d['world.gravity']}: no gravity (on Earth: [0.0, 0.0, -9.81])"),
        "",
        ("# [[loads]]", "optional, zero or more external loads, each constant over a step"),
        ("# force = [1.0, 0.0, 0.0]", "N, world frame; acts at the COM unless point or body_point is given"),
        ("# point = [0.0, 0.0, 0.0]", "m, world frame: a point fixed in the world; or"),
        ("# body_point = [0.0, 0.1, 0.0]", "m, body frame: a point of the body (moves with it)"),
        ("# torque = [0.0, 0.0, 1.0]", "N m, world frame: a pure couple"),
        ("# body_torque = [0.0, 0.0, 1.0]", "N m, body frame: a couple that turns with the body"),
        ("# start = 0.0", "s, default 0.0: acts from the first step time t_k = k dt >= start"),
        ("# steps = 1", "acts on this many steps; or"),
        ("# end = 0.5", "s: acts while t_k < end; neither steps nor end: to the end of the run"),
    ]


def _toml(value) -> str:
    """A TOML value: a basic string of printable characters (quotes and backslashes escaped), or
    a list of floats."""
    if isinstance(value, str):
        return '"' + "".join("\\" + ch if ch in '"\\' else ch for ch in value) + '"'
    return "[" + ", ".join(repr(float(x)) for x in value) + "]"


# --- the parser -------------------------------------------------------------------------------

def parse_case(data: dict, source: str = "<case>") -> Problem:
    """Validate a case's TOML data (as from ``tomllib``) into a :class:`Problem`."""
    c = _Ctx(source)
    c.keys(data, TOP_KEYS, "", required=REQUIRED_TOP_KEYS)
    name = data["name"]
    if not isinstance(name, str) or not name.strip():
        c.fail("name", "must be a non-empty string")
    if len(name) > CASE_NAME_MAX_CHARS:
        c.fail("name", f"is {len(name)} characters long; at most {CASE_NAME_MAX_CHARS} "
                       f"(CASE_NAME_MAX_CHARS): {abbreviated(name, 40)}")
    if not name.isprintable():
        c.fail("name", f"must be printable text, without control characters or terminal escape "
                       f"sequences, got {abbreviated(name)}")
    description = data.get("description", DEFAULTS["description"])
    if not isinstance(description, str):
        c.fail("description", "must be a string")

    dts: tuple[float, ...] = ()  # none in the file: --dt must give them (check_run_settings)
    if "dt" in data:
        dts_raw = data["dt"]
        dts_list = dts_raw if isinstance(dts_raw, list) else [dts_raw]
        if not dts_list:
            c.fail("dt", "must list at least one time step")
        if len(dts_list) > MAX_TIME_STEPS_PER_CASE:
            c.fail("dt", f"lists {len(dts_list)} time steps; a case lists at most {MAX_TIME_STEPS_PER_CASE} "
                         f"(MAX_TIME_STEPS_PER_CASE: each one is a run per engine and integrator)")
        dts = tuple(c.number(d, "dt", positive=True, tiny_ok=True) for d in dts_list)

    if "duration" in data and "duration_steps" in data:
        c.fail("duration", "give exactly one of duration (s) and duration_steps, not both "
                           "(or neither, and --duration on the command line)")
    duration = duration_steps = None  # neither: --duration must give it (check_run_settings)
    if "duration" in data:
        duration = c.number(data["duration"], "duration", positive=True, tiny_ok=True)
        for d in dts:
            if duration < d * (1 - tol.DURATION_VS_DT_RTOL):
                c.fail("duration", f"{duration} s is shorter than dt = {d} s")
            check_step_count(duration, d, lambda why: c.fail("duration", why))
    elif "duration_steps" in data:
        duration_steps = c.integer(data["duration_steps"], "duration_steps",
                                   maximum=tol.MAX_STEPS_PER_RUN, why_maximum=" (MAX_STEPS_PER_RUN)")
    for d in dts:  # after the step count, which says more about a tiny dt
        if d < tol.INPUT_POSITIVE_MIN:
            c.fail("dt", f"must be at least {tol.INPUT_POSITIVE_MIN:g} s (smaller steps are too small to "
                         f"compute with in float64), got {d!r}")

    body = _parse_body(c, data["body"])
    initial = _parse_initial(c, data.get("initial", {}))
    world = data.get("world", {})  # no [world]: no gravity (DEFAULTS; defaulted_keys says so)
    c.keys(world, WORLD_KEYS, "world")
    gravity = c.vector(world.get("gravity", DEFAULTS["world.gravity"]), "world.gravity", 3)

    loads_raw = data.get("loads", [])
    if not isinstance(loads_raw, list):
        c.fail("loads", "must be an array of tables ([[loads]])")
    loads = tuple(_parse_load(c, ld, i) for i, ld in enumerate(loads_raw))
    return Problem(name=name, description=description, body=body, initial=initial,
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
        if not isinstance(shape, str):
            c.fail("body.shape", f"must be a shape name (a string), got {abbreviated(shape)}; known: "
                                 f"{', '.join(massprops.SHAPES)}")
        if shape not in massprops.SHAPES:
            c.fail("body.shape", f"unknown shape {abbreviated(shape)}; known: {', '.join(massprops.SHAPES)}")
        if "size" not in b:
            c.fail("body.size", "missing required key (with shape)")
        size = c.vector(b["size"], "body.size", massprops.SHAPES[shape], positive=True)
        if ("mass" in b) == ("density" in b):
            c.fail("body.mass", "give exactly one of mass and density (with shape)")
        if "mass" in b:
            mass = c.number(b["mass"], "body.mass", positive=True)
        else:
            density = c.number(b["density"], "body.density", positive=True)
            volume = massprops.volume(shape, size)
            validate_volume(volume, lambda why: c.fail("body.size", f"a {shape} of this size: {why}"))
            mass = density * volume
            validate_mass(mass, lambda why: c.fail("body.density", f"with this size, the {why}"))
        I = massprops.inertia(shape, size, mass)
    validate_inertia(I, lambda why: c.fail("body.inertia" if has_inertia else "body.size",
                                           why if has_inertia else f"the {shape}'s inertia: {why}"))
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
    validate_volume(props.volume, lambda why: c.fail("body.mesh", f"{path}: {why}"))
    validate_mass(props.mass, lambda why: c.fail(f"body.{key}", f"with this mesh, the {why}"))
    validate_inertia(props.inertia, lambda why: c.fail("body.mesh", f"{path}: inertia {why}"))
    return Body(mass=props.mass, I_body=props.inertia)


def _parse_initial(c: _Ctx, t) -> InitialState:
    """[initial], every key optional (DEFAULTS: at rest at the origin, unrotated)."""
    c.keys(t, INITIAL_KEYS, "initial")

    def get(key):
        return t.get(key, DEFAULTS[f"initial.{key}"])

    q = _orientation(c, get("orientation"))
    n = float(np.linalg.norm(q))
    if abs(n - 1) > tol.UNIT_QUATERNION_RTOL:
        warnings.warn(f"{c.source}: initial.orientation: |q| = {n:.6g}, normalised to a unit "
                      "quaternion", CaseWarning, stacklevel=2)
    return InitialState(position=c.vector(get("position"), "initial.position", 3), quaternion_wxyz=q / n,
                        linear_velocity=c.vector(get("linear_velocity"), "initial.linear_velocity", 3),
                        angular_velocity=c.vector(get("angular_velocity"), "initial.angular_velocity", 3))


def _orientation(c: _Ctx, value) -> np.ndarray:
    """initial.orientation (w, x, y, z): not zero, and with a norm that float64 can compute."""
    key = "initial.orientation"
    if not isinstance(value, list) or len(value) != 4:
        c.fail(key, f"must be a list of 4 numbers, got {abbreviated(value)}")
    q = np.array([c.number(v, f"{key}[{i}]") for i, v in enumerate(value)])
    largest = float(np.max(np.abs(q)))
    if largest == 0:
        c.fail(key, "is the zero quaternion (w, x, y, z); identity is [1, 0, 0, 0]")
    n = float(np.linalg.norm(q))
    if largest < tol.INPUT_POSITIVE_MIN or not (n > 0 and math.isfinite(n)):  # squares vanish or overflow
        c.fail(key, f"{abbreviated(value)} is too small to normalise (its squares vanish in float64: "
                    f"denormal); give a unit quaternion such as [1, 0, 0, 0]")
    return q


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
        kw["steps"] = c.integer(ld["steps"], f"{where}.steps", maximum=tol.MAX_STEPS_PER_RUN,
                                why_maximum=" (MAX_STEPS_PER_RUN; leave steps out to act to the end)")
    if "end" in ld:
        end = c.number(ld["end"], f"{where}.end")
        if end <= start:
            c.fail(f"{where}.end", f"must be after start ({start} s), got {end}")
        kw["end"] = end
    return Load(start=start, **kw)
