"""results.json (schema version 7) and the per-run trajectory files, written atomically.

results.json::

    {"schema_version": 7, "freebody_version", "created", "platform", "engines": {name: version},
     "conventions": {name: [[convention, text], ...]}, "incomplete": false,
     "runs": [RunResult.to_json(), ...], ...}

Schema 2 added each run's ``experiment`` (what was simulated: :mod:`freebody.run.experiment`)
and, in ``cases``, the time steps and durations that ran (``ran``).  Schema 1 documents (and
baselines) are still read: their runs' ``experiment`` is unknown (null after the migration), and
``freebody compare`` then matches runs on their identity and steps and says that their content
could not be checked.

Schema 3 added, in ``cases``, ``defaults``: the optional case-file keys a case left out and so got
by default (e.g. ``world.gravity``: no ``[world]``, no gravity), and engine names may carry a
version (``mujoco==3.1.6``, an engine run in an isolated environment).  Schema 2 and 1 documents
are still read (their cases' ``defaults`` are unknown, null: they say nothing about them).

Schema 4 (issue 26: verdicts that never mislead) added, per run, ``load_sampling`` (how the
engine's step saw the loads: ``per-stage`` | ``per-step``, null without loads), ``state_growth``
(how far |w| and the kinetic energy grew beyond the truth's, the blow-up time, the largest rotation
per step and the engine's declared cap) and, in ``matches_reference``, ``verdict``
(``reproduces`` | ``indistinguishable`` | ``closest`` | ``undecidable``) and ``undecidable``; in
``cases``, ``state_dependent_loads``.  On load, an older document's ``matches_reference`` gets the
verdict its other keys imply (:func:`freebody.results.identification.implied_verdict`) and the
other new keys are null (unknown).

Schema 5 (issue 27: judging in one place) added, per run, ``judgement``: the facts its findings
present (blow-up, rotation cap, the map it reproduces or comes closest to, saturation, its formal
order; :mod:`freebody.results.judgement`), computed once when the run is recorded; an older
document's runs get theirs on load from their stored fields, by the same function.

Schema 6 (issue 28) added, in each judged run's ``metrics``, ``quaternion_norm_error_max``
(max_k |1 - |q_k|| of the quaternions as the engine handed them out) and, in its ``judgement``,
``non_unit_quaternion`` (that beyond round-off: a finding).  An older run's metric is null
(unknown) and its ``non_unit_quaternion`` false.

Schema 7 (issue 29: the report in its budget) added ``conventions``: per engine whose adapter the
run loaded, its conventions as ``freebody conventions`` states them (the adapter's ``conventions``,
then its load sampling), so that a report reads them without importing the engine (MJX's adapter
imports JAX).  An older document has none: its report imports the adapters, as before.

Every document read is migrated on load (:func:`load_results` -> :func:`migrate`, one
``_update_to_N`` per schema version, asv's ``update_to_N``), so that readers see the newest shape
only; the keys it guarantees, and those that stay optional, are listed above :func:`_update_to_2`.

Renamed reference integrators (``symplectic-euler`` is now ``lie-euler``) do not change the format
and bump no schema version: every document read, of either version, has the old names replaced by
the current ones (:func:`upgrade_names`), so that an old baseline still matches today's runs.

Written with sorted keys; non-finite numbers become null (the run's status says why).  Readers
ignore keys they do not know.  A run's trajectory file (npz) gives the run's arrays and its truth's:
``t (N,)``, ``position (N, 3)``, ``quaternion_wxyz (N, 4)``, ``linear_velocity (N, 3)``,
``angular_velocity (N, 3)`` [, ``orthonormality_error (N,)``], and the same with a ``truth_`` prefix,
at the saved samples (see :data:`SAVED_SAMPLES`), and ``sample_index (N,)`` int64, the step k of each
saved sample (t = k dt; files of early releases lack it).  Trajectory format 2 (issue 29: this
release on; :data:`TRAJECTORY_FORMAT`, written into each file's ``layout``) stores a (case, dt)'s
truth once, in a truth file ``truth__<hash>.npz`` beside its runs' files that each run's file names,
leaves out ``t`` when it is ``sample_index * dt``, and stores the samples XOR-delta'd and
byte-shuffled (lossless); format 1 (each array under its name in the run's file) is still read.
Readers open either through :func:`open_trajectory` / :func:`load_trajectory`, which give the same
arrays by the same names, bit for bit.
A run's ``trajectory`` is its file's path relative to the folder of results.json:
``trajectories/<n>/<name>.npz``, one folder ``<n>`` per invocation (see :mod:`.outdir`), or
``trajectories/<name>.npz`` in folders written by earlier releases.  Readers open it only through
:func:`open_run_trajectory`: a regular file inside that folder, of at most the bytes the run's steps
allow (a results file is data, not a path to follow; any other is the run's missing trajectory).
"""
from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import zipfile
import zlib
from collections.abc import Mapping
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from .. import __version__
from ..errors import InputError, abbreviated, printable
from ..numbers import finite_or_none
from ..adapters.base import REFERENCE_ENGINE
from ..reference_impl.conventions import Trajectory
from ..reference_impl.integrators import INTEGRATOR_ALIASES
from .io import FileRefused, open_regular_file, read_json, write_npz_atomic

SCHEMA_VERSION = 7
READABLE_SCHEMA_VERSIONS = (1, 2, 3, 4, 5, 6, 7)  # results.json / baseline versions this freebody reads
_FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity")


def document_header(schema_version: int, engines: dict[str, str | None] | None = None, **fields) -> dict:
    """The fields every freebody JSON document (results, sweep, bench, inertia) opens with:
    ``schema_version`` (that of the document's kind), ``freebody_version``, ``created`` (UTC, to the
    second), ``platform`` (OS, machine, Python) and, if given, ``engines`` {name: version or None};
    then ``fields`` in their order (a field may replace one of these, e.g. bench's detailed platform)."""
    doc = {
        "schema_version": schema_version,
        "freebody_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "platform": f"{platform.system()} {platform.machine()} Python {platform.python_version()}",
    }
    if engines is not None:
        doc["engines"] = engines
    doc.update(fields)
    return doc


def results_document(runs: list[dict], engines: dict[str, str | None], incomplete: bool = False,
                     extra: dict | None = None, conventions: dict[str, list] | None = None) -> dict:
    """results.json's document; ``conventions``: engine -> [[convention, text], ...] (schema 7)."""
    fields = {"conventions": conventions} if conventions is not None else {}
    doc = document_header(SCHEMA_VERSION, engines, **fields, incomplete=incomplete, runs=runs)
    doc.update(extra or {})
    return doc


READABLE_NAME_CHARS = 120  # of a trajectory file name's readable part (the whole name stays < 160)


def trajectory_filename(run: dict) -> str:
    """The file name (no folder) of a run's trajectory file: a readable part (case, engine,
    integrator, precision, dt; ASCII letters, digits and ``._-``, the rest ``_``, at most
    READABLE_NAME_CHARS) and a hash of the run's exact identity (case, engine, integrator,
    precision, ``repr(dt)``, steps), so that two runs never share a file (cases "x y" and "x_y",
    dt 0.01 and 0.0100000001) and a long case name still makes a valid file name."""
    precision = run.get("precision", "float64")
    identity = json.dumps([run["case"], run["engine"], run["integrator"], precision,
                           repr(float(run["dt"])), run.get("steps")])
    digest = hashlib.sha256(identity.encode("utf-8")).hexdigest()[:12]
    readable = f"{run['case']}__{run['engine']}__{run['integrator']}__{precision}__dt{run['dt']:g}"
    safe = "".join(ch if ch.isascii() and (ch.isalnum() or ch in "._-") else "_" for ch in readable)
    if safe.startswith("."):
        safe = "_" + safe[1:]  # no hidden files
    return f"{safe[:READABLE_NAME_CHARS]}__{digest}.npz"


# --save-every auto (the default): a run's trajectory file keeps at most SAVED_SAMPLES samples, every
# k-th step with k = ceil(steps / SAVED_SAMPLES) (all of them for a run of fewer steps), plus the
# samples listed by saved_indices.  The report's figures draw a panel about 450 pixels wide, so
# 800 evenly spaced samples are nearly 2 per pixel column; with them the default suite's 735 runs
# wrote 47 MB of trajectory files (1000: 62 MB; every step: 336 MB; docs/benchmarks.md); its 1551
# runs of every default engine 78.8 MB in format 1, 31.7 MB in format 2 (docs/reports.md, Size).
# Metrics always use every step; --save-every 1 keeps every sample.
SAVED_SAMPLES = 800


def auto_every(n_samples: int) -> int:
    """The stride --save-every auto uses for a run of ``n_samples`` samples (steps + 1)."""
    return max(1, -(-(int(n_samples) - 1) // SAVED_SAMPLES))


def finite_argmax(a) -> int | None:
    """The first index of the largest finite value of ``a`` (None if none is finite): the sample a
    trajectory file keeps of a series' maximum."""
    a = np.asarray(a, dtype=float)
    finite = np.isfinite(a)
    if not finite.any():
        return None
    return int(np.argmax(np.where(finite, a, -np.inf)))


def saved_indices(n: int, every: int, series=None, diverged_index: int | None = None,
                  orthonormality: np.ndarray | None = None) -> np.ndarray:
    """The sample indices (ascending, int64, shape (K,)) a trajectory file keeps of a run of ``n``
    samples: every ``every``-th, the last, and when thinned (``every`` > 1) the sample of each
    series' maximum (orientation, angular momentum, energy and position errors of
    :class:`freebody.run.metrics.Series`, the orthonormality error; over the whole run and over
    the samples before a divergence) and the two samples around a divergence, so that the figures
    show every maximum the metrics report and where a run blew up (:func:`select_saved`)."""
    maxima = []
    if every > 1:
        arrays = [] if series is None else [series.orientation_error, series.angular_momentum_error,
                                             series.energy_error, series.position_error]
        if orthonormality is not None:
            arrays.append(orthonormality)
        ends = [n] if diverged_index is None else [n, prefix_end(diverged_index, n)]
        for arr in arrays:
            for end in ends:
                i = finite_argmax(arr[:end])
                if i is not None:
                    maxima.append(i)
    return select_saved(n, every, maxima, diverged_index)


def prefix_end(diverged_index: int, n: int) -> int:
    """The end of the samples "before the divergence" whose maxima a trajectory file keeps (at
    least the first sample)."""
    return max(1, min(diverged_index, n))


def select_saved(n: int, every: int, maxima, diverged_index: int | None = None) -> np.ndarray:
    """The rule of :func:`saved_indices` given the indices of the maxima (``maxima``, kept when
    ``every`` > 1): a run judged in chunks finds them as it goes."""
    picks = [np.arange(0, n, every), [n - 1]]
    if every > 1:
        picks.append(list(maxima))
        if diverged_index is not None:
            picks.append([max(0, min(diverged_index, n - 1) - 1), min(diverged_index, n - 1)])
    return np.unique(np.concatenate([np.asarray(p, dtype=np.int64) for p in picks]))


def samples_to_save(tr: Trajectory, truth: Trajectory | None, every: int | None = None, series=None,
                    diverged_at: float | None = None, index: np.ndarray | None = None
                    ) -> tuple[Trajectory, Trajectory | None, np.ndarray]:
    """(run, truth, sample indices) as a trajectory file stores them: the truth cut to the run's
    samples (a diverged run stops early) without orthonormality, both reduced to the samples of
    :func:`saved_indices` (``every`` None: :func:`auto_every`).  ``index``: ``tr`` and ``truth``
    are already the saved samples, at these indices (a run judged in chunks keeps no more)."""
    if index is not None:
        return tr, None if truth is None else truth.without_orthonormality(), np.asarray(index, np.int64)
    n = len(tr)
    if truth is not None:
        truth = truth.head(n).without_orthonormality()
    every = auto_every(n) if every is None else every
    d = None if diverged_at is None else int(np.searchsorted(tr.t, diverged_at))
    idx = saved_indices(n, every, series, d, tr.orthonormality_error) if n else np.zeros(0, np.int64)
    if len(idx) < n:
        tr = tr.take(idx)
        truth = truth.take(idx) if truth is not None else None
    return tr, truth, idx


# --- trajectory files: format 2 (one truth file shared by the runs that have its samples) ---------
#
# A run's file (format 2) holds, as members of an npz archive (each an .npy, np.load reads them):
#   layout        0-d str: JSON {"trajectory_format": 2, "dt": dt or null, "columns": [field, ...],
#                 "truth": null | {"file": name or null, "columns": [field, ...]}}
#   sample_index  (K,) int64, the step k of each saved sample, ascending
#   samples       (8 K C,) uint8: the run's columns as a (K, C) float64 block (:func:`encode_block`)
#   truth_extra   (8 K' C',) uint8: the truth's columns at the run's samples its truth file lacks
# Columns are fields of :data:`_FIELDS` (and ``orthonormality_error``), in that order; each is one
# column (t, orthonormality_error) or its width (position 3, quaternion_wxyz 4, velocities 3).
# ``t`` is a column only when it is not ``sample_index * dt`` bit for bit (``dt`` null); the truth's
# ``t`` only when it is not the run's.  A truth file ``truth__<12 hex>.npz`` beside the run's holds
# ``layout`` ({"trajectory_format": 2, "kind": "truth", "columns": [...]}), ``sample_index`` (S,)
# and ``samples``: the truth at the samples every run of its (case, dt) keeps (its stride and last
# sample); its name is a hash of its content, so runs share it exactly when their truths agree there,
# and a second writer writes the same bytes.  A file without ``layout`` is format 1 (every array
# under its own name, the truth's with a ``truth_`` prefix); both read the same
# (:func:`open_trajectory`).
TRAJECTORY_FORMAT = 2
READABLE_TRAJECTORY_FORMATS = (1, 2)  # trajectory file formats this freebody reads
LAYOUT = "layout"
TRUTH_FILE = re.compile(r"truth__[0-9a-f]{12}\.npz")  # a shared truth file's name (nothing else)
ORTHONORMALITY = "orthonormality_error"
_WIDTH = {"t": 0, "position": 3, "quaternion_wxyz": 4, "linear_velocity": 3, "angular_velocity": 3,
          ORTHONORMALITY: 0}  # 0: a (K,) column; w: (K, w)
_COLUMNS = (*_FIELDS, ORTHONORMALITY)


def encode_block(block: np.ndarray) -> np.ndarray:
    """A (K, C) float64 block as the uint8 array (8 K C,) a format-2 file stores, losslessly: each
    row's bits XOR the previous row's (a smooth series leaves its sign, exponent and leading mantissa
    bits zero), columns one after another, then the bytes shuffled (the first byte of every value,
    then the second, ...), which deflate compresses about a fifth smaller than the raw values (the
    default suite's run samples: 35.1 -> 27.9 MB)."""
    u = np.ascontiguousarray(block, dtype="<f8").view("<u8")
    d = u.copy()
    d[1:] ^= u[:-1]
    return np.ascontiguousarray(np.ascontiguousarray(d.T).view(np.uint8).reshape(-1, 8).T).reshape(-1)


def decode_block(data: np.ndarray, rows: int, columns: int) -> np.ndarray:
    """The (rows, columns) float64 block :func:`encode_block` made ``data`` of, bit for bit."""
    d = np.ascontiguousarray(data.reshape(8, rows * columns).T).view("<u8").reshape(columns, rows).T
    return np.bitwise_xor.accumulate(d, axis=0).view("<f8").astype(np.float64, copy=False)


def _width(field: str) -> int:
    return max(1, _WIDTH[field])


def _block(x: Trajectory, fields: list[str], rows: int) -> np.ndarray:
    """The (rows, C) float64 block of the fields ``fields`` of ``x``, in that order."""
    return np.hstack([getattr(x, f).reshape(rows, _width(f)) for f in fields]) if fields else np.zeros((rows, 0))


def _split(block: np.ndarray, fields: list[str]) -> dict[str, np.ndarray]:
    """A decoded block's columns as arrays by field ((K,) or (K, w), C-contiguous copies)."""
    out, c = {}, 0
    for f in fields:
        w = _width(f)
        part = block[:, c:c + w]
        out[f] = np.ascontiguousarray(part[:, 0] if _WIDTH[f] == 0 else part)
        c += w
    return out


def grid_times(index: np.ndarray, dt: float) -> np.ndarray:
    """t (K,) s of samples at steps ``index`` on a fixed step ``dt``: ``index * dt``, the product
    :meth:`Trajectory.on_grid` forms."""
    return index * dt


def _grid_dt(t: np.ndarray, index: np.ndarray) -> float | None:
    """A step dt with ``grid_times(index, dt)`` equal to ``t`` bit for bit, or None."""
    nonzero = np.flatnonzero(index)
    if len(t) == 0:
        return None
    if len(nonzero) == 0:
        candidates = [0.0]
    else:
        q = float(t[nonzero[-1]] / index[nonzero[-1]])
        candidates = [q, float(np.nextafter(q, np.inf)), float(np.nextafter(q, -np.inf))]
    for dt in candidates:
        if np.isfinite(dt) and grid_times(index, dt).tobytes() == t.tobytes():
            return dt
    return None


def shared_rows(index: np.ndarray) -> np.ndarray:
    """Which of a run's saved samples (steps ``index``, ascending) its truth file holds: those on the
    stride of its file (every k-th step, k the most frequent gap) and its last one, the samples
    every run of its (case, dt) keeps; the maxima and divergence samples are the run's own."""
    if len(index) < 2:
        return np.ones(len(index), bool)
    gaps, counts = np.unique(np.diff(index), return_counts=True)
    every = int(gaps[np.argmax(counts)])
    return (index % every == 0) | (index == index[-1])


def _format2_arrays(tr: Trajectory, truth: Trajectory | None, index: np.ndarray) -> bool:
    """Whether a run's samples fit format 2 (float64 fields of K rows at K ascending steps); a
    trajectory built otherwise by hand is written in format 1, as it is."""
    k = len(index)
    if np.any(np.diff(index) <= 0):
        return False
    for x in (tr, truth):
        if x is None:
            continue
        for f in _COLUMNS:
            a = getattr(x, f)
            shape = (k,) if _WIDTH[f] == 0 else (k, _WIDTH[f])
            if a is not None and (not isinstance(a, np.ndarray) or a.dtype != np.float64 or a.shape != shape):
                return False
    return True


def write_trajectory(path: Path, tr: Trajectory, truth: Trajectory | None, index: np.ndarray,
                     trajectory_format: int = TRAJECTORY_FORMAT) -> None:
    """Write a run's saved samples (from :func:`samples_to_save`) to ``path`` atomically, in format
    :data:`TRAJECTORY_FORMAT` (its truth at the shared samples in a truth file beside it, written
    once: see above), or in format 1 (one file, each array under its name, as earlier releases wrote
    it) when ``trajectory_format`` is 1 or format 2 does not hold the arrays (:func:`_format2_arrays`)."""
    path, index = Path(path), np.asarray(index, dtype=np.int64)
    if trajectory_format not in READABLE_TRAJECTORY_FORMATS:
        raise ValueError(f"trajectory format {trajectory_format}: freebody writes formats "
                         f"{', '.join(map(str, READABLE_TRAJECTORY_FORMATS))}")
    if trajectory_format == 1 or not _format2_arrays(tr, truth, index):
        _write_format1(path, tr, truth, index)
        return
    dt = _grid_dt(tr.t, index)
    fields = [f for f in _COLUMNS if getattr(tr, f) is not None and (f != "t" or dt is None)]
    layout = {"trajectory_format": TRAJECTORY_FORMAT, "dt": dt, "columns": fields, "truth": None}
    arrays = {"sample_index": index, "samples": encode_block(_block(tr, fields, len(index)))}
    if truth is not None:
        layout["truth"], arrays["truth_extra"] = _share_truth(path.parent, tr, truth, index)
    arrays[LAYOUT] = np.array(json.dumps(layout, sort_keys=True))
    write_npz_atomic(path, arrays)


def _share_truth(folder: Path, tr: Trajectory, truth: Trajectory, index: np.ndarray) -> tuple[dict, np.ndarray]:
    """(the run's layout ``truth`` entry, its ``truth_extra`` member): the truth at the shared rows
    (:func:`shared_rows`) goes to the truth file of that content in ``folder`` (written if it is not
    there yet), the rest stays in the run's file."""
    fields = [f for f in _FIELDS if f != "t" or truth.t.tobytes() != tr.t.tobytes()]
    block = _block(truth, fields, len(index))
    rows = shared_rows(index)
    name = _write_truth_file(folder, index[rows], block[rows], fields) if rows.any() else None
    return {"file": name, "columns": fields}, encode_block(block[~rows])


def _write_truth_file(folder: Path, index: np.ndarray, block: np.ndarray, fields: list[str]) -> str:
    """The name of the truth file holding ``block`` (S, C) at the steps ``index`` (S,) in ``folder``,
    written atomically unless it is there already (its name is a hash of its content)."""
    layout = json.dumps({"trajectory_format": TRAJECTORY_FORMAT, "kind": "truth", "columns": fields},
                        sort_keys=True)
    digest = hashlib.sha256(b"\0".join([layout.encode(), index.tobytes(), block.tobytes()])).hexdigest()
    name = f"truth__{digest[:12]}.npz"
    if not os.path.isfile(folder / name) or os.path.islink(folder / name):
        write_npz_atomic(folder / name, {LAYOUT: np.array(layout), "sample_index": index,
                                         "samples": encode_block(block)})
    return name


def _write_format1(path: Path, tr: Trajectory, truth: Trajectory | None, index: np.ndarray) -> None:
    """The format-1 file of a run: each array under its name, the truth's with a ``truth_`` prefix."""
    arrays = {f: getattr(tr, f) for f in _FIELDS}
    arrays["sample_index"] = index
    if tr.orthonormality_error is not None:
        arrays[ORTHONORMALITY] = tr.orthonormality_error
    if truth is not None:
        arrays.update({"truth_" + f: getattr(truth, f) for f in _FIELDS})
    write_npz_atomic(path, arrays)


def load_trajectory(path: Path, limit: int | None = None) -> tuple[Trajectory, Trajectory | None]:
    """(run trajectory, truth trajectory or None) from a trajectory file of either format (a regular
    file, not a symbolic link, of at most ``limit`` bytes, default TRAJECTORY_FILE_MAX_BYTES:
    :func:`open_trajectory`; a format-2 file's truth file is read from the same folder)."""
    with open_trajectory(path, TRAJECTORY_FILE_MAX_BYTES if limit is None else limit) as z:
        tr = Trajectory(*(z[f] for f in _FIELDS), orthonormality_error=z.get(ORTHONORMALITY))
        truth = Trajectory(*(z["truth_" + f] for f in _FIELDS)) if "truth_t" in z else None
    return tr, truth


# --- reading a run's trajectory file: data, not a path to follow ---------------------------------
#
# A run's ``trajectory`` comes from a results document, which anyone may have written: it is read
# only when it names a regular file inside the document's folder (:func:`trajectory_path`: relative,
# no "..", no symbolic link leading out of the folder; :func:`open_npz`: no FIFO, device, socket or
# folder, opened non-blocking), of at most :func:`trajectory_max_bytes` (on the disk and
# uncompressed), so that no results file makes a report open /etc/passwd, block on a FIFO or read
# /dev/zero.  Any other is the run's missing trajectory, with a warning (:func:`usable_trajectories`).
#
# A trajectory file's bytes per saved sample: at most 16 arrays of float64 / int64 values (run: t 1,
# position 3, quaternion 4, velocities 3 + 3, orthonormality 1, sample_index 1; truth: 14) = 30 x 8
# (format 1; a format-2 run file or truth file holds fewer, and each is held to the same bound).
TRAJECTORY_BYTES_PER_SAMPLE = 30 * 8
# What a trajectory file holds besides its samples: the zip's directory and a .npy header per array
# (16 arrays of ~200 bytes; format 2's layout text, ~1.5 KB), with room to spare.
TRAJECTORY_FIXED_BYTES = 64 * 1024
# At most, whatever a run's steps say (and for a run that does not say): 2 GiB is a run of 8.9
# million steps saved at every step (--save-every 1); the default keeps ~800 samples (~200 KB).
TRAJECTORY_FILE_MAX_BYTES = 2 * 2 ** 30


def trajectory_max_bytes(run: dict) -> int:
    """The most a run's trajectory file may hold (on the disk, and uncompressed): its samples, at
    most one per step and the first (steps + 1), TRAJECTORY_BYTES_PER_SAMPLE each, plus
    TRAJECTORY_FIXED_BYTES; TRAJECTORY_FILE_MAX_BYTES when larger or the run's steps are unknown."""
    steps = run.get("steps")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        return TRAJECTORY_FILE_MAX_BYTES
    return min(TRAJECTORY_FILE_MAX_BYTES, TRAJECTORY_FIXED_BYTES + TRAJECTORY_BYTES_PER_SAMPLE * (steps + 1))


def trajectory_path(folder: Path, rel) -> Path:
    """The file a run's ``trajectory`` ``rel`` names in the results folder ``folder`` (symbolic
    links resolved), or FileRefused (what: the path as written; reason: why it is not read): an
    absolute path, a ".." part, or a path that resolves outside ``folder`` (a symbolic link to
    another folder) is not read."""
    what = f"trajectory {printable(str(rel))}"
    if not isinstance(rel, str) or not rel or "\x00" in rel:
        raise FileRefused(what, "not a file name")
    if PurePosixPath(rel).is_absolute() or PureWindowsPath(rel).anchor:
        raise FileRefused(what, "an absolute path; a run's trajectory is a path inside its results folder")
    if ".." in PurePosixPath(rel).parts or ".." in PureWindowsPath(rel).parts:
        raise FileRefused(what, "leads out of its results folder (..)")
    root = os.path.realpath(folder)
    real = os.path.realpath(os.path.join(root, rel))
    if os.path.commonpath([root, real]) != root:
        raise FileRefused(what, f"a symbolic link out of its results folder (to {printable(real)})")
    return Path(real)


@contextmanager
def open_npz(path: Path, limit: int, what: str | None = None):
    """The npz file ``path`` opened (``np.load``, no pickles) when it is a regular file, not a
    symbolic link, of at most ``limit`` bytes on the disk and uncompressed; else FileRefused."""
    what = what or printable(str(path))
    fd = open_regular_file(path, limit, what, follow_symlinks=False)
    with os.fdopen(fd, "rb") as f:
        try:
            z = np.load(f, allow_pickle=False)
        except (ValueError, OSError, zipfile.BadZipFile, EOFError) as e:
            raise FileRefused(what, f"not a trajectory file ({type(e).__name__})") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise FileRefused(what, "not a trajectory file (not an npz archive)")
        with z:
            size = sum(i.file_size for i in z.zip.infolist())
            if size > limit:
                raise FileRefused(what, f"too large: {size} bytes uncompressed, more than the {limit} "
                                        f"its run's steps allow")
            yield z


class TrajectoryArrays(Mapping):
    """An open trajectory file's arrays under their format-1 names, whatever its format: ``t`` (K,)
    s, ``position`` (K, 3) m, ``quaternion_wxyz`` (K, 4), ``linear_velocity`` (K, 3) m/s,
    ``angular_velocity`` (K, 3) rad/s (world frame, canonical convention), ``sample_index`` (K,)
    int64 (files of earlier releases may lack it), ``orthonormality_error`` (K,) (matrix
    integrators), and the truth's at the same samples ``truth_t`` ... ``truth_angular_velocity``.
    A missing array is a KeyError, as in an npz file.  ``format``: the file's format number."""

    format = 1

    def __init__(self, z):
        self._z = z

    def __getitem__(self, name: str) -> np.ndarray:
        return self._z[name]

    def __iter__(self):
        return iter(self._z.files)

    def __len__(self) -> int:
        return len(self._z.files)

    @property
    def files(self) -> list[str]:
        return list(self)

    def truth_key(self) -> tuple | None:
        """A key equal for two files exactly when their truth arrays are (CRC-32 and sizes of what
        holds them), so that a reader reduces each distinct truth once; None without a truth."""
        try:
            return tuple((i.CRC, i.file_size) for i in (self._z.zip.getinfo(f"truth_{f}.npy") for f in _FIELDS))
        except KeyError:
            return None


class _Format2(TrajectoryArrays):
    """A format-2 run file (see :data:`TRAJECTORY_FORMAT`); its truth file is opened by
    ``open_truth(name)`` (a context manager yielding the open npz) when a truth array is first read."""

    format = 2

    def __init__(self, z, layout: dict, what: str, open_truth):
        super().__init__(z)
        self._layout, self._what, self._open_truth = layout, what, open_truth
        self._index = _member(z, "sample_index", what, np.int64)
        k = len(self._index)
        run = _split(_decoded(z, "samples", k, layout["columns"], what), layout["columns"])
        if "t" not in run:
            run["t"] = grid_times(self._index, layout["dt"])
        self._arrays, self._truth = {"sample_index": self._index, **run}, None
        truth = layout["truth"]
        self._names = [*self._arrays] + ([f"truth_{f}" for f in _FIELDS] if truth is not None else [])

    def __getitem__(self, name: str) -> np.ndarray:
        if name.startswith("truth_") and name in self._names:
            if self._truth is None:
                self._truth = self._read_truth()
            return self._truth[name]
        return self._arrays[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def truth_key(self) -> tuple | None:
        if self._layout["truth"] is None:
            return None
        z = self._z.zip
        members = ["sample_index", "truth_extra"] + (["samples"] if "t" in self._layout["columns"] else [])
        return (2, json.dumps(self._layout, sort_keys=True),
                *((i.CRC, i.file_size) for i in (z.getinfo(m + ".npy") for m in members)))

    def _read_truth(self) -> dict[str, np.ndarray]:
        """The truth's arrays at the run's samples: the truth file's rows at the samples it holds,
        the run file's ``truth_extra`` rows at the others."""
        entry, index = self._layout["truth"], self._index
        fields = entry["columns"]
        block = np.empty((len(index), sum(_width(f) for f in fields)))
        mine = np.ones(len(index), bool)
        if entry["file"] is not None:
            with self._open_truth(entry["file"]) as t:
                shared, shared_index = _shared_truth_block(t, fields, f"truth file {entry['file']}")
            pos = np.searchsorted(shared_index, index)
            pos[pos == len(shared_index)] = 0
            mine = shared_index[pos] != index if len(shared_index) else mine
            block[~mine] = shared[pos[~mine]]
        block[mine] = _decoded(self._z, "truth_extra", int(mine.sum()), fields, self._what)
        out = {f"truth_{f}": a for f, a in _split(block, fields).items()}
        out.setdefault("truth_t", self._arrays["t"].copy())
        return out


def _member(z, name: str, what: str, dtype) -> np.ndarray:
    """Member ``name`` of an open npz ``z``, a 1-D array of ``dtype``; FileRefused otherwise."""
    try:
        a = z[name]
    except KeyError:
        raise FileRefused(what, f"not a trajectory file (no {name})") from None
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:  # a damaged member
        raise FileRefused(what, f"not a trajectory file ({name}: {type(e).__name__})") from None
    if a.ndim != 1 or a.dtype != dtype:
        raise FileRefused(what, f"not a trajectory file ({name} is {a.dtype} {a.shape})")
    return a


def _decoded(z, name: str, rows: int, fields: list[str], what: str) -> np.ndarray:
    """The (rows, C) float64 block stored as member ``name`` (:func:`decode_block`)."""
    data = _member(z, name, what, np.uint8)
    columns = sum(_width(f) for f in fields)
    if len(data) != 8 * rows * columns:
        raise FileRefused(what, f"not a trajectory file ({name} holds {len(data)} bytes, not "
                                f"{rows} x {columns} values)")
    return decode_block(data, rows, columns)


# Truth files' blocks read in this process (_shared_truth_block): the runs of a case at one dt share
# one truth file, read once for all of them (a report reads a figure's runs one after another).
_TRUTH_BLOCKS: dict = {}
TRUTH_BLOCKS_KEPT = 4


def _shared_truth_block(z, fields: list[str], what: str) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_truth_file_block` of an open truth file, kept (read-only) for the next run naming
    the same file: the same file on the disk (device, inode, size, modification and change times
    of the file opened) read for the same columns."""
    st = os.fstat(z.zip.fp.fileno())
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns, tuple(fields))
    if key not in _TRUTH_BLOCKS:
        block, index = _truth_file_block(z, fields, what)
        block.setflags(write=False)
        index.setflags(write=False)
        if len(_TRUTH_BLOCKS) >= TRUTH_BLOCKS_KEPT:
            del _TRUTH_BLOCKS[next(iter(_TRUTH_BLOCKS))]
        _TRUTH_BLOCKS[key] = block, index
    return _TRUTH_BLOCKS[key]


def _truth_file_block(z, fields: list[str], what: str) -> tuple[np.ndarray, np.ndarray]:
    """(block (S, C), steps (S,)) of an open truth file whose columns are ``fields``."""
    layout = _layout(z, what)
    if layout.get("kind") != "truth" or layout.get("columns") != fields:
        raise FileRefused(what, "not the truth file its run names (its columns differ)")
    index = _member(z, "sample_index", what, np.int64)
    if np.any(np.diff(index) <= 0):
        raise FileRefused(what, "not a truth file (its samples are not ascending)")
    return _decoded(z, "samples", len(index), fields, what), index


def _layout(z, what: str) -> dict:
    """The ``layout`` of an open format-2 file, checked: FileRefused for a newer or unknown format."""
    try:
        layout = json.loads(str(z[LAYOUT][()]))
    except (ValueError, TypeError, IndexError) as e:
        raise FileRefused(what, f"not a trajectory file (its layout: {type(e).__name__})") from None
    version = layout.get("trajectory_format") if isinstance(layout, dict) else None
    if version not in READABLE_TRAJECTORY_FORMATS:
        raise FileRefused(what, f"trajectory format {printable(str(version))}: this freebody reads formats "
                                f"{', '.join(map(str, READABLE_TRAJECTORY_FORMATS))}; read it with the freebody "
                                f"that wrote it, or re-run the suite")
    columns = layout.get("columns")
    if not isinstance(columns, list) or any(c not in _WIDTH for c in columns):
        raise FileRefused(what, "not a trajectory file (unknown columns in its layout)")
    return layout


def _run_layout(z, what: str) -> dict:
    """A format-2 run file's layout, checked (:func:`_layout`, then its dt and truth entry)."""
    layout = _layout(z, what)
    dt, truth = layout.get("dt"), layout.get("truth")
    columns = layout["columns"]
    if any(f not in columns for f in _FIELDS[1:]) or (dt is None) != ("t" in columns) or not (
            dt is None or isinstance(dt, float)):
        raise FileRefused(what, "not a trajectory file (its layout lacks a field or its step)")
    if truth is not None and not (isinstance(truth, dict) and isinstance(truth.get("columns"), list)
                                  and all(f in _FIELDS for f in truth["columns"])
                                  and all(f in truth["columns"] for f in _FIELDS[1:])
                                  and (truth.get("file") is None or (isinstance(truth["file"], str)
                                                                     and TRUTH_FILE.fullmatch(truth["file"])))):
        raise FileRefused(what, "not a trajectory file (its truth entry)")
    return layout


@contextmanager
def open_trajectory(path: Path, limit: int, what: str | None = None, truth_path=None):
    """A trajectory file (either format) opened as :class:`TrajectoryArrays`, through
    :func:`open_npz` (a regular file, not a symbolic link, of at most ``limit`` bytes); a format-2
    file's truth file, ``truth_path(name)`` (default: beside ``path``), is opened the same way
    when a truth array is first read.  FileRefused for anything else."""
    what = what or printable(str(path))
    locate = truth_path or (lambda name: Path(path).parent / name)

    @contextmanager
    def open_truth(name: str):
        try:
            with open_npz(locate(name), limit, f"{what}: its truth file {name}") as t:
                yield t
        except FileRefused as e:  # the run's own file is fine: say that its truth file is not
            raise FileRefused(what, f"its truth file {name}: {e.reason}") from None

    with open_npz(path, limit, what) as z:
        if LAYOUT not in z.files:
            yield TrajectoryArrays(z)
        else:
            yield _Format2(z, _run_layout(z, what), what, open_truth)


@contextmanager
def open_run_trajectory(folder: Path, run: dict):
    """A run's trajectory file in the results folder ``folder``, opened as
    :class:`TrajectoryArrays` (:func:`open_trajectory`) when it is a regular file inside the folder
    (:func:`trajectory_path`) of at most :func:`trajectory_max_bytes`, and so is its truth file
    (format 2: beside it, as ``run["trajectory"]`` names it); else FileRefused (its ``reason`` says
    why)."""
    rel = run["trajectory"]
    path = trajectory_path(folder, rel)
    beside = PurePosixPath(rel).parent
    with open_trajectory(path, trajectory_max_bytes(run), f"trajectory {printable(str(rel))}",
                         lambda name: trajectory_path(folder, str(beside / name))) as z:
        yield z


def trajectory_problem(folder: Path, run: dict) -> str | None:
    """Why a run's trajectory file is not read (:func:`open_run_trajectory`), or None when it is
    usable or the run has none."""
    if not run.get("trajectory"):
        return None
    try:
        path = trajectory_path(folder, run["trajectory"])
        os.close(open_regular_file(path, trajectory_max_bytes(run), "", follow_symlinks=False))
    except FileRefused as e:
        return e.reason
    return None


def usable_trajectories(doc: dict, folder: Path) -> tuple[dict, list[str]]:
    """(``doc`` with the ``trajectory`` of each run whose file is not read set to None, one line per
    such run naming it and the reason).  A run of a results document read from ``folder``: its
    trajectory is read only when :func:`trajectory_problem` finds nothing; ``doc`` is not modified."""
    runs, lines = [], []
    for i, r in enumerate(doc["runs"]):
        why = trajectory_problem(folder, r)
        if why is not None:
            lines.append(f"runs[{i}] ({printable(r['case'])} {printable(r['engine'])}/"
                         f"{printable(r['integrator'])} dt={r['dt']}): trajectory "
                         f"{abbreviated(r['trajectory'], 80)} treated as missing: {why}")
            r = {**r, "trajectory": None}
        runs.append(r)
    return ({**doc, "runs": runs} if lines else doc), lines


REQUIRED_RUN_KEYS = ("case", "engine", "integrator", "dt", "status")
MIGRATE = ("to migrate, re-run the suite with this freebody (freebody run ... --out DIR) and store a new "
           "baseline (freebody baseline DIR --to FILE --force), or compare with the freebody release that "
           "wrote it")


def load_results(source, role: str = "") -> dict:
    """A results document from a run directory, a results.json or baseline file, or a dict.

    role : e.g. "baseline" or "current", named in error messages.  InputError on anything unusable
    (missing file, bad JSON, another schema version: the message says how to migrate, malformed runs).
    The one reader of results documents: what it returns is in the newest shape (:func:`migrate`).
    """
    prefix = f"{role} " if role else ""
    if isinstance(source, dict):
        return check_results(source, f"{prefix}(in memory)")
    p = Path(source)
    if p.is_dir():
        if not (p / "results.json").is_file():
            raise InputError(f"{prefix}{printable(p)}: no results.json in this directory (run freebody run "
                             f"--out {printable(p)})")
        p = p / "results.json"
    where = f"{prefix}{printable(p)}"
    try:
        doc = read_json(p, where)
    except UnicodeDecodeError as e:  # e.g. UTF-16 or Latin-1
        raise InputError(f"{where}: not UTF-8 text (byte {e.start}); freebody writes results as "
                         f"UTF-8 JSON") from None
    except RecursionError:
        raise InputError(f"{where}: not a results file: its JSON is nested too deeply") from None
    return check_results(doc, where)


# The types of a run's fields (keys of RunResult.to_json) that readers use: a field that is present
# must have one of them (None: JSON null).  Unknown keys are ignored.
_NUMBER = (int, float)
_RUN_FIELD_TYPES = {
    "case": (str,), "engine": (str,), "integrator": (str,), "status": (str,),
    "precision": (str, type(None)), "steps": (int, type(None)), "message": (str, type(None)),
    "truth": (str, type(None)), "trajectory": (str, type(None)), "engine_version": (str, type(None)),
    "metrics": (dict, type(None)), "final_state": (dict, type(None)), "engine_settings": (dict, type(None)),
    "matches_reference": (dict, type(None)), "vs_engine": (dict, type(None)), "engine_output": (list, type(None)),
    "wall_time_s": (*_NUMBER, type(None)), "diverged_at_s": (*_NUMBER, type(None)),
    "compile_time_s": (*_NUMBER, type(None)), "experiment": (dict, type(None)),
    "state_growth": (dict, type(None)), "judgement": (dict, type(None)),
}
_JSON_TYPE = {str: "a string", int: "an integer", float: "a number", dict: "an object", list: "an array",
              type(None): "null"}


def _json_type(value) -> str:
    return "a boolean" if isinstance(value, bool) else _JSON_TYPE.get(type(value), type(value).__name__)


# The types of the other parts of a document that readers (report, compare, baseline, findings)
# index, as freebody writes them (run/convergence.py, report/render.augment, results/baseline.py,
# results/judgement.py, run/judge.py); a part that is present must have one of them.  Objects keyed
# by names (``cases``, ``levels_rad``, ...) are checked entry by entry.
_NULL = type(None)
_OPT_NUMBER = (*_NUMBER, _NULL)
_OPT_STR = (str, _NULL)
_DOC_FIELD_TYPES = {"freebody_version": _OPT_STR, "created": _OPT_STR, "platform": _OPT_STR,
                    "cases": (dict, _NULL), "convergence": (list, _NULL), "baseline": (dict, _NULL)}
_CASE_FIELD_TYPES = {"description": _OPT_STR, "truth": _OPT_STR, "mass": _OPT_NUMBER, "inertia": (list, _NULL),
                     "gravity": (list, _NULL), "dts": (list, _NULL), "ran": (list, _NULL),
                     "defaults": (list, _NULL), "state_dependent_loads": (bool, _NULL),
                     "torque_free": (bool, _NULL), "duration": _OPT_NUMBER, "duration_steps": (int, _NULL)}
_RAN_FIELD_TYPES = {"dt": _NUMBER, "steps": (int, _NULL), "duration_s": _OPT_NUMBER}
_CONVERGENCE_REQUIRED = ("case", "engine", "integrator", "metric")
_CONVERGENCE_FIELD_TYPES = {"case": (str,), "engine": (str,), "integrator": (str,), "metric": (str,),
                            "precision": _OPT_STR, "order": _OPT_NUMBER, "dts": (list, _NULL),
                            "errors": (list, _NULL), "fitted_dts": (list, _NULL),
                            "log10_coefficient": _OPT_NUMBER, "fit_rms_decades": _OPT_NUMBER,
                            "saturated": (bool, _NULL), "reason": _OPT_STR}
_BASELINE_FIELD_TYPES = {"source": _OPT_STR, "runs": (int, _NULL)}
_MATCH_FIELD_TYPES = {"verdict": _OPT_STR, "integrator": _OPT_STR, "closest": _OPT_STR,
                      "max_orientation_diff_rad": _OPT_NUMBER, "threshold_rad": _OPT_NUMBER, "rule": _OPT_STR,
                      "indistinguishable": (list, _NULL), "undecidable": (list, _NULL),
                      "levels_rad": (dict, _NULL), "ratios": (dict, _NULL), "candidates": (dict, _NULL)}
_JUDGEMENT_FIELD_TYPES = {"scheme": _OPT_STR, "reproduced": (bool, _NULL), "schemes": (list,),
                          "scheme_distance_rad": _OPT_NUMBER, "scheme_level_rad": _OPT_NUMBER,
                          "scheme_ratio": _OPT_NUMBER, "saturated": (bool,), "order": (int, _NULL),
                          "order_maps": (list,), "blew_up": (bool,), "capped": (bool,)}
_FINAL_STATE_FIELD_TYPES = {"t": _OPT_NUMBER, "quaternion_wxyz": (list, _NULL), "angular_velocity": (list, _NULL),
                            "linear_velocity": (list, _NULL), "position": (list, _NULL)}
_EXPERIMENT_FIELD_TYPES = {"dt": _OPT_NUMBER, "steps": (int, _NULL), "duration_s": _OPT_NUMBER,
                           "settings": (dict, _NULL)}


def _check_fields(obj: dict, types: dict, where: str) -> None:
    """InputError naming ``<where><key>`` (``where`` ends with ": " or ".") when a key of ``obj``
    listed in ``types`` has a value of none of its types (a JSON boolean is one only where ``bool``
    is listed: it is no number)."""
    for k, allowed in types.items():
        x = obj.get(k)
        if k not in obj or (isinstance(x, bool) and bool in allowed):
            continue
        if isinstance(x, bool) or not isinstance(x, allowed):
            kinds = " or ".join(_JSON_TYPE.get(t, "true or false") for t in dict.fromkeys(allowed))
            raise InputError(f"{where}{printable(str(k))}: must be {kinds}, got {_json_type(x)}: "
                             f"{abbreviated(x, 40)}")


def _object(x, where: str) -> dict:
    if not isinstance(x, dict):
        raise InputError(f"{where}: must be an object, got {_json_type(x)}: {abbreviated(x, 40)}")
    return x


def _check_items(items, allowed: tuple, where: str) -> None:
    """Each entry of a list (``where[i]``) of one of the ``allowed`` types (no boolean as a number)."""
    for i, x in enumerate(items or []):
        if isinstance(x, bool) or not isinstance(x, allowed):
            kind = "a number" if allowed == _NUMBER else _JSON_TYPE[allowed[0]]
            raise InputError(f"{where}[{i}]: must be {kind}, got {_json_type(x)}")


def _check_parts(doc: dict, where: str) -> None:
    """The types of the document's parts besides its runs (:data:`_DOC_FIELD_TYPES`): ``cases``
    (each an object, :data:`_CASE_FIELD_TYPES`, its ``ran`` entries), ``convergence`` (each an
    object naming its case, engine, integrator and metric), ``baseline``."""
    _check_fields(doc, _DOC_FIELD_TYPES, f"{where}: ")
    for name, rec in (doc.get("cases") or {}).items():
        at = f"{where}: cases.{printable(str(name))}"
        _check_fields(_object(rec, at), _CASE_FIELD_TYPES, f"{at}.")
        for i, ran in enumerate(rec.get("ran") or []):
            _check_fields(_object(ran, f"{at}.ran[{i}]"), _RAN_FIELD_TYPES, f"{at}.ran[{i}].")
        _check_items(rec.get("dts"), _NUMBER, f"{at}.dts")
        _check_items(rec.get("defaults"), (str,), f"{at}.defaults")
    for i, e in enumerate(doc.get("convergence") or []):
        at = f"{where}: convergence[{i}]"
        for k in _CONVERGENCE_REQUIRED:
            if k not in _object(e, at):
                raise InputError(f"{at}.{k}: missing")
        _check_fields(e, _CONVERGENCE_FIELD_TYPES, f"{at}.")
    if doc.get("baseline") is not None:
        _check_fields(doc["baseline"], _BASELINE_FIELD_TYPES, f"{where}: baseline.")


def _check_run_parts(r: dict, where: str) -> None:
    """The types of a run's objects that readers index: ``matches_reference`` (its map names,
    numbers, lists of names and objects of numbers), ``judgement``, ``final_state``,
    ``experiment``, ``state_growth`` (numbers or null)."""
    m = r.get("matches_reference")
    if m is not None:
        _check_fields(m, _MATCH_FIELD_TYPES, f"{where}.matches_reference.")
        for k in ("indistinguishable", "undecidable"):
            _check_items(m.get(k), (str,), f"{where}.matches_reference.{k}")
        for k in ("levels_rad", "ratios", "candidates"):
            named = m.get(k) or {}
            _check_fields(named, dict.fromkeys(named, _OPT_NUMBER), f"{where}.matches_reference.{k}.")
    for k, types in (("judgement", _JUDGEMENT_FIELD_TYPES), ("final_state", _FINAL_STATE_FIELD_TYPES),
                     ("experiment", _EXPERIMENT_FIELD_TYPES)):
        if r.get(k) is not None:
            _check_fields(r[k], types, f"{where}.{k}.")
    growth = r.get("state_growth") or {}
    _check_fields(growth, dict.fromkeys(growth, _OPT_NUMBER), f"{where}.state_growth.")


def check_results(doc, where: str) -> dict:
    """Validate a loaded results document: its schema version, ``engines``, ``incomplete`` and every
    run's identity, status and the types of the fields readers use (:data:`_RUN_FIELD_TYPES`);
    InputError naming ``where`` and the field.  Returns a copy in the newest shape
    (:func:`migrate`) with the current names of reference maps (:func:`upgrade_names`)."""
    from ..run.records import STATUSES

    if not isinstance(doc, dict) or "schema_version" not in doc:
        raise InputError(f"{where}: schema_version: missing; not a freebody results or baseline file")
    v = doc["schema_version"]
    if isinstance(v, bool) or v not in READABLE_SCHEMA_VERSIONS:
        raise InputError(f"{where}: schema_version: is {abbreviated(v)}, this freebody reads "
                         f"{' and '.join(map(str, READABLE_SCHEMA_VERSIONS))}; {MIGRATE}")
    engines = doc.get("engines")
    if engines is not None:
        if not isinstance(engines, dict):
            raise InputError(f"{where}: engines: must be an object {{engine: version or null}}, got "
                             f"{_json_type(engines)}")
        for e, ver in engines.items():
            if ver is not None and not isinstance(ver, str):
                raise InputError(f"{where}: engines.{printable(e)}: must be a version string or null, got "
                                 f"{_json_type(ver)}")
    if not isinstance(doc.get("incomplete", False), bool):
        raise InputError(f"{where}: incomplete: must be true or false, got {_json_type(doc['incomplete'])}")
    runs = doc.get("runs")
    if not isinstance(runs, list):
        raise InputError(f"{where}: runs: missing or not a list")
    _check_parts(doc, where)
    for i, r in enumerate(runs):
        _check_run(r, f"{where}: runs[{i}]", STATUSES)
        _check_run_parts(r, f"{where}: runs[{i}]")
    return upgrade_names(migrate(doc))


# --- migrations on load (asv's update_to_N) --------------------------------------------------------
#
# Every document read goes through :func:`load_results` (report, compare, baseline, run --baseline,
# the Python API), which validates it and brings it to the newest shape: one step per schema version
# (:data:`_MIGRATIONS`), then :func:`_complete`.  Readers (compare, verdict, report, findings) see
# that shape only and index the keys it guarantees:
#
# - the document: ``schema_version`` (as written: it says what was written), ``engines`` ({} when
#   absent), ``incomplete`` (False when absent), ``runs``; optional, also in the newest schema:
#   ``cases`` and ``convergence`` (absent from an interrupted run's results), ``baseline``,
#   ``conventions`` (schema 7; absent before).
# - every run: every key of :class:`freebody.run.records.RunResult` (:data:`RUN_DEFAULTS`, a key
#   absent from the file gets its value there: None, {} or []; ``precision`` null or absent is
#   "float64"; ``metrics``, ``engine_settings`` null are {}, ``engine_output`` null is []).  What
#   an old file cannot carry is None, "unknown": ``experiment`` of a schema-1 run (compare then
#   matches on steps and says that the content could not be checked), ``load_sampling`` and
#   ``state_growth`` of a run written before schema 4.  ``judgement`` is never None: a run without
#   one (written before schema 5, or by hand) gets it from its other fields
#   (:func:`freebody.results.judgement.run_judgement`, the function the run layer calls).
# - every ``matches_reference`` that is a dict: ``verdict`` (one of
#   :data:`freebody.results.identification.VERDICTS`), ``integrator``, ``closest``,
#   ``max_orientation_diff_rad``, ``indistinguishable`` and ``undecidable`` (lists), ``levels_rad``
#   and ``ratios`` (objects, {} when the file has none); optional: ``candidates``,
#   ``threshold_rad``, ``rule``.
# - every entry of ``cases`` that is a dict: ``defaults`` (None: unknown, written before schema 3),
#   ``ran`` (None before schema 2) and ``state_dependent_loads`` (None before schema 4).
#
# A step is idempotent (it fills what is absent), works on copies (the caller's dicts are not
# modified) and ignores malformed parts that validation lets through.  Adding schema N is one step
# ``_update_to_N`` and one line in _MIGRATIONS.

def _runs(doc: dict) -> list[dict]:
    """The document's runs that are objects (copied in place in ``doc["runs"]`` by :func:`migrate`)."""
    return [r for r in doc.get("runs") or [] if isinstance(r, dict)]


def _judged(doc: dict) -> list[dict]:
    """The ``matches_reference`` objects of the document's runs (copies, see :func:`migrate`)."""
    return [r["matches_reference"] for r in _runs(doc) if isinstance(r.get("matches_reference"), dict)]


def _case_records(doc: dict) -> list[dict]:
    cases = doc.get("cases")
    return [c for c in cases.values() if isinstance(c, dict)] if isinstance(cases, dict) else []


def _update_to_2(doc: dict) -> dict:
    """Schema 1 -> 2: a run's ``experiment`` is unknown (None); a case's ``ran`` (the time steps
    and durations run) is unknown.  Identification then recorded no ties, levels or ratios: a
    named map is its own tie, and the levels and ratios are empty."""
    for r in _runs(doc):
        r.setdefault("experiment", None)
    for m in _judged(doc):
        if "indistinguishable" not in m:
            m["indistinguishable"] = [m["integrator"]] if isinstance(m.get("integrator"), str) else []
        m.setdefault("levels_rad", {})
        m.setdefault("ratios", {})
    for c in _case_records(doc):
        c.setdefault("ran", None)
    return doc


def _update_to_3(doc: dict) -> dict:
    """Schema 2 -> 3: a case's ``defaults`` (the optional case-file keys it left out) are unknown."""
    for c in _case_records(doc):
        c.setdefault("defaults", None)
    return doc


def _update_to_4(doc: dict) -> dict:
    """Schema 3 -> 4: each ``matches_reference`` gets the ``verdict`` its other keys imply (as
    those files' readers took them: :func:`freebody.results.identification.implied_verdict`) and
    ``undecidable`` [] (no map was found undecidable then); a run's ``load_sampling`` and
    ``state_growth`` and a case's ``state_dependent_loads`` are unknown (None)."""
    from .identification import implied_verdict

    for r in _runs(doc):
        r.setdefault("load_sampling", None)
        r.setdefault("state_growth", None)
    for m in _judged(doc):
        if "verdict" not in m:
            m["verdict"] = implied_verdict(m)
        m.setdefault("undecidable", [])
    for c in _case_records(doc):
        c.setdefault("state_dependent_loads", None)
    return doc


def _update_to_5(doc: dict) -> dict:
    """Schema 4 -> 5: each run gets its ``judgement`` (:mod:`freebody.results.judgement`), computed
    from its stored fields by the function the run layer calls when it records a run (map names
    brought up to date first, as every reader sees them), so an old document's findings are today's."""
    from .judgement import with_judgement
    doc = upgrade_names(doc)
    return {**doc, "runs": [with_judgement(r) for r in doc.get("runs", [])]}


def _update_to_6(doc: dict) -> dict:
    """Schema 5 -> 6: a judged run's (non-empty ``metrics``) ``quaternion_norm_error_max`` is
    unknown (None), and its ``judgement`` gets ``non_unit_quaternion`` (False: unknown is no finding)."""
    from ..run.metrics import QUATERNION_NORM_ERROR_MAX
    from .judgement import JUDGEMENT, non_unit_quaternion

    for r in _runs(doc):
        if isinstance(r.get("metrics"), dict) and r["metrics"]:
            r["metrics"] = {QUATERNION_NORM_ERROR_MAX: None, **r["metrics"]}
        if isinstance(r.get(JUDGEMENT), dict) and "non_unit_quaternion" not in r[JUDGEMENT]:
            r[JUDGEMENT] = {**r[JUDGEMENT], "non_unit_quaternion": non_unit_quaternion(r)}
    return doc


def _update_to_7(doc: dict) -> dict:
    """Schema 7 added ``conventions`` (engine -> [[convention, text], ...]), optional: an older
    document has none, and its readers (the report) ask the adapters instead."""
    return doc


# One step per schema version: step N brings a document of version N - 1 to N.
_MIGRATIONS = {2: _update_to_2, 3: _update_to_3, 4: _update_to_4, 5: _update_to_5, 6: _update_to_6,
               7: _update_to_7}

# Every run key (RunResult.to_json) and its value when a file leaves it out (never for the five
# REQUIRED_RUN_KEYS, checked on load).
RUN_DEFAULTS = {"precision": "float64", "steps": None, "message": "", "truth": None, "metrics": {},
                "final_state": None, "wall_time_s": None, "engine_version": None, "engine_settings": {},
                "matches_reference": None, "diverged_at_s": None, "trajectory": None, "engine_output": [],
                "vs_engine": None, "compile_time_s": None, "experiment": None, "state_growth": None,
                "load_sampling": None, "judgement": None}
_NULL_MEANS_DEFAULT = ("precision", "metrics", "engine_settings", "engine_output")


def _complete(doc: dict) -> dict:
    """The keys every document of the newest shape has (see above), filled where a file (of any
    version: a hand-made one, a trimmed one) leaves them out."""
    if doc.get("engines") is None:
        doc["engines"] = {}
    doc.setdefault("incomplete", False)
    for r in _runs(doc):
        _complete_run(r)
    return doc


def _complete_run(r: dict) -> None:
    """Fill, in place, what a run of the newest shape has (see above :func:`_update_to_2`)."""
    from .identification import VERDICTS, implied_verdict
    from .judgement import JUDGEMENT, run_judgement

    for k, v in RUN_DEFAULTS.items():
        if k not in r or (r[k] is None and k in _NULL_MEANS_DEFAULT):
            r[k] = type(v)() if isinstance(v, (dict, list)) else v
    m = r["matches_reference"]
    if isinstance(m, dict):
        if m.get("verdict") not in VERDICTS:  # a hand-made file's: read as its other keys imply
            m["verdict"] = implied_verdict(m)
        for k in ("integrator", "closest", "max_orientation_diff_rad"):
            m.setdefault(k, None)
        for k, kind in (("indistinguishable", list), ("undecidable", list), ("levels_rad", dict), ("ratios", dict)):
            if not isinstance(m.get(k), kind):  # absent, or null in a hand-made file
                m[k] = kind()
    if r[JUDGEMENT] is None:  # a hand-made file's (freebody writes it; _update_to_5 fills older ones')
        r[JUDGEMENT] = run_judgement(r)


def complete_run(run: dict) -> dict:
    """A copy of a run built by hand (a results.json ``runs`` entry, e.g. in a test) in the newest
    shape, as :func:`load_results` gives every run: its absent keys filled (:data:`RUN_DEFAULTS`),
    its ``matches_reference`` completed, its ``judgement`` computed when it has none."""
    out = {**run, "matches_reference": dict(run["matches_reference"])} \
        if isinstance(run.get("matches_reference"), dict) else dict(run)
    _complete_run(out)
    return out


def _copied(doc: dict) -> dict:
    """A copy of ``doc`` whose runs, their ``matches_reference``, ``cases`` and case records are
    copies too: the parts the migration steps fill in."""
    out = dict(doc)
    if isinstance(doc.get("runs"), list):
        out["runs"] = [{**r, "matches_reference": dict(r["matches_reference"])}
                       if isinstance(r, dict) and isinstance(r.get("matches_reference"), dict)
                       else dict(r) if isinstance(r, dict) else r for r in doc["runs"]]
    if isinstance(doc.get("cases"), dict):
        out["cases"] = {k: dict(c) if isinstance(c, dict) else c for k, c in doc["cases"].items()}
    return out


def migrate(doc: dict) -> dict:
    """A copy of ``doc`` in the newest shape: one step of :data:`_MIGRATIONS` per version it is
    behind, then the keys every document has (:func:`_complete`; the guaranteed and the optional
    keys are listed above :func:`_update_to_2`).  Its ``schema_version`` is kept (it says what was
    written); ``doc`` itself is not modified."""
    doc = _copied(doc)
    for target in range(int(doc["schema_version"]) + 1, SCHEMA_VERSION + 1):
        doc = _MIGRATIONS[target](doc)
    return _complete(doc)


# The fields of a run's matches_reference that hold a reference map's name, a list of them, an
# object keyed by them (freebody.run.judge.identify)
_MAP_NAME_FIELDS = ("integrator", "closest")
_MAP_NAME_LISTS = ("indistinguishable", "undecidable")
_MAP_NAME_KEYED = ("candidates", "levels_rad", "ratios")


def upgrade_names(doc: dict, aliases: dict[str, str] | None = None) -> dict:
    """``doc`` with the old names of reference integrators replaced by the current ones.

    aliases : old name -> current name; default
        :data:`freebody.reference_impl.integrators.INTEGRATOR_ALIASES` (``symplectic-euler`` ->
        ``lie-euler``).

    Renamed: the ``integrator`` of a reference engine run and of a reference engine entry of
    ``convergence``; the map names of any run's ``matches_reference`` (``integrator``, ``closest``,
    ``indistinguishable`` and the keys of ``candidates``, ``levels_rad`` and ``ratios``).  So
    ``freebody compare`` of a baseline stored before a rename matches ``reference/symplectic-euler``
    with ``reference/lie-euler``, and an engine run that reproduced ``symplectic-euler`` then and
    ``lie-euler`` now is no scheme change.  Applied to every document read (:func:`check_results`),
    whatever its schema version: a rename changes no format, so it bumps no schema version.  A
    run's ``trajectory`` path (its file name may hold the old name) is kept: it names the file.
    ``doc`` itself is not modified: it is returned as it is when no name changes, else a copy whose
    changed runs and entries are copies.
    """
    aliases = INTEGRATOR_ALIASES if aliases is None else aliases
    if not aliases:
        return doc

    def name(x):
        return aliases.get(x, x) if isinstance(x, str) else x

    def map_names(m: dict):
        yield from (m.get(k) for k in _MAP_NAME_FIELDS)
        for k in (*_MAP_NAME_LISTS, *_MAP_NAME_KEYED):
            if isinstance(m.get(k), (list, dict)):
                yield from m[k]

    def stale(e: dict) -> bool:
        m = e.get("matches_reference")
        return ((e.get("engine") == REFERENCE_ENGINE and name(e.get("integrator")) != e.get("integrator"))
                or (isinstance(m, dict) and any(name(x) != x for x in map_names(m) if isinstance(x, str))))

    def upgraded(e: dict) -> dict:
        """A copy of a run or convergence entry with its names brought up to date."""
        out = dict(e)
        if e.get("engine") == REFERENCE_ENGINE and "integrator" in e:
            out["integrator"] = name(e["integrator"])
        m = e.get("matches_reference")
        if isinstance(m, dict):
            m = dict(m)
            for k in _MAP_NAME_FIELDS:
                if k in m:
                    m[k] = name(m[k])
            for k in _MAP_NAME_LISTS:
                if isinstance(m.get(k), list):
                    m[k] = [name(x) for x in m[k]]
            for k in _MAP_NAME_KEYED:
                if isinstance(m.get(k), dict):
                    m[k] = {name(x): v for x, v in m[k].items()}
            out["matches_reference"] = m
        if isinstance(e.get("judgement"), dict):  # its map names are those above: the same facts, new names
            from .judgement import run_judgement

            out["judgement"] = run_judgement(out)
        return out

    out = doc
    for key in ("runs", "convergence"):
        entries = doc.get(key)
        if isinstance(entries, list) and any(isinstance(e, dict) and stale(e) for e in entries):
            out = dict(out) if out is doc else out
            out[key] = [upgraded(e) if isinstance(e, dict) and stale(e) else e for e in entries]
    return out


def _check_run(r, where: str, statuses) -> None:
    if not isinstance(r, dict):
        raise InputError(f"{where}: not an object")
    for k in REQUIRED_RUN_KEYS:
        if k not in r:
            raise InputError(f"{where}.{k}: missing")
    for k, types in _RUN_FIELD_TYPES.items():
        if k in r and (isinstance(r[k], bool) or not isinstance(r[k], types)):
            kinds = " or ".join(_JSON_TYPE[t] for t in dict.fromkeys(types))
            raise InputError(f"{where}.{k}: must be {kinds}, got {_json_type(r[k])}: {abbreviated(r[k], 40)}")
    if r["status"] not in statuses:
        raise InputError(f"{where}.status: unknown status {abbreviated(r['status'], 40)}; known: "
                         f"{', '.join(statuses)}")
    dt = r["dt"]
    if finite_or_none(dt) is None or dt <= 0:
        raise InputError(f"{where}.dt: not a positive number: {abbreviated(dt, 40)}")
    for m, x in (r.get("metrics") or {}).items():
        if x is not None and (isinstance(x, bool) or not isinstance(x, _NUMBER)):
            raise InputError(f"{where}.metrics.{printable(m)}: must be a number or null, got {_json_type(x)}")
