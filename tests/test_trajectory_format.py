"""Trajectory files, format 2 (issue 29: default output <= 50 MB of trajectories): a (case, dt)'s
truth stored once in a truth file its runs name, ``t`` not stored when it is ``sample_index * dt``,
samples XOR-delta'd and byte-shuffled before deflate; and format 1 (every file written before) read
as before, arrays bit for bit (golden folder tests/golden/trajectory_format1, written by freebody
e1ea532).
"""
from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from freebody.errors import InputError
from freebody.report import data as rd
from freebody.results.document import (TRAJECTORY_FORMAT, TRUTH_FILE, decode_block, encode_block,
                                       load_trajectory, open_run_trajectory, open_trajectory, samples_to_save,
                                       shared_rows, write_trajectory)
from freebody.results.io import write_npz_atomic
from freebody.results.outdir import OutputFolder, output_lock
from freebody.reference_impl.conventions import Trajectory

GOLDEN = Path(__file__).parent / "golden" / "trajectory_format1"
FIELDS = ("t", "position", "quaternion_wxyz", "linear_velocity", "angular_velocity", "orthonormality_error")


def _same(a, b) -> bool:
    """Bit for bit: shape, dtype and bytes (NaN payloads and -0.0 included)."""
    if a is None or b is None:
        return a is None and b is None
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def _assert_same(x: Trajectory | None, y: Trajectory | None) -> None:
    assert (x is None) == (y is None)
    if x is not None:
        for f in FIELDS:
            assert _same(getattr(x, f), getattr(y, f)), f


def _motion(n: int, dt: float, seed: int, ortho: bool = False) -> Trajectory:
    """A smooth random motion of n samples at t = k dt (Trajectory.on_grid), float64."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0, 1, n)[:, None]
    q = np.cos(s * rng.uniform(1, 3, 4) + rng.uniform(0, 1, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    tr = Trajectory.on_grid(0, dt, np.sin(s * rng.uniform(1, 2, 3)), q, np.cos(s * rng.uniform(1, 2, 3)),
                            np.sin(3 * s + rng.uniform(0, 1, 3)))
    if ortho:
        tr = Trajectory(tr.t, tr.position, tr.quaternion_wxyz, tr.linear_velocity, tr.angular_velocity,
                        rng.uniform(0, 1e-15, n))
    return tr


# --- the block codec --------------------------------------------------------------------------

def test_block_codec_is_lossless_bit_for_bit():
    rng = np.random.default_rng(0)
    block = rng.standard_normal((50, 7))
    block[3, 2], block[4, 1], block[5, 0] = np.nan, -0.0, np.inf
    block[6, 3] = np.frombuffer(np.uint64(0x7FF8000000000123).tobytes(), np.float64)[0]  # a NaN payload
    data = encode_block(block)
    assert data.dtype == np.uint8 and data.shape == (8 * 50 * 7,)
    assert _same(decode_block(data, 50, 7), block)
    assert _same(decode_block(encode_block(np.zeros((0, 3))), 0, 3), np.zeros((0, 3)))


def test_block_codec_compresses_a_smooth_series_better_than_its_raw_bytes():
    """The point of the codec: a smooth series (an integrator's samples) deflates smaller."""
    import zlib

    block = _motion(800, 0.001, 1).quaternion_wxyz
    assert len(zlib.compress(encode_block(block).tobytes(), 6)) < 0.9 * len(zlib.compress(block.tobytes(), 6))


# --- format 2: written, read back bit for bit ---------------------------------------------------

def _save(folder: Path, tr: Trajectory, truth: Trajectory | None, every: int | None = None, series=None):
    """Save a run as the harness does (samples_to_save, then write_trajectory); its path, its
    saved (trajectory, truth, index)."""
    saved = samples_to_save(tr, truth, every, series)
    path = folder / f"run{len(list(folder.glob('run*.npz')))}__{'0' * 12}.npz"
    write_trajectory(path, *saved)
    return path, saved


def test_format2_reads_back_what_was_saved(tmp_path):
    tr, truth = _motion(2001, 0.001, 2, ortho=True), _motion(2001, 0.001, 3)
    path, (s_tr, s_truth, idx) = _save(tmp_path, tr, truth)
    got_tr, got_truth = load_trajectory(path)
    _assert_same(got_tr, s_tr)
    _assert_same(got_truth, s_truth)
    with np.load(path) as z:  # an npz np.load opens: the format, the steps, no t (it is k dt)
        layout = json.loads(str(z["layout"][()]))
        assert layout["trajectory_format"] == TRAJECTORY_FORMAT == 2 and layout["dt"] == 0.001
        assert "t" not in layout["columns"] and _same(z["sample_index"], idx)
        assert "truth_t" not in z.files and "truth_extra" in z.files
    assert TRUTH_FILE.fullmatch(layout["truth"]["file"]) and (tmp_path / layout["truth"]["file"]).is_file()


def test_a_truth_file_rewritten_is_read_anew(tmp_path):
    """The truth block kept for the next run of a truth file is not used once that file changed."""
    from freebody.results import document as D

    truth = _motion(401, 0.01, 7)
    path, (_, s_truth, _) = _save(tmp_path, _motion(401, 0.01, 8), truth)
    _assert_same(load_trajectory(path)[1], s_truth)
    (truth_file,) = tmp_path.glob("truth__*.npz")
    with np.load(truth_file) as z:
        arrays = {k: z[k] for k in z.files}
    block, index = D._truth_file_block(np.load(truth_file), json.loads(str(arrays["layout"][()]))["columns"], "")
    write_npz_atomic(truth_file, {**arrays, "samples": encode_block(block + 1.0)})  # another truth, same name
    got = load_trajectory(path)[1]
    assert np.array_equal(got.position, s_truth.position + 1.0)


def test_runs_of_one_truth_share_one_truth_file(tmp_path):
    """Runs of a (case, dt) keep their own maxima besides the common stride: the truth at the stride
    is stored once, each run's own samples in its file; every run reads its whole truth back."""
    truth = _motion(5001, 0.001, 4)
    saved = []
    for seed in range(3):
        saved.append(_save(tmp_path, _motion(5001, 0.001, 10 + seed), truth, series=_Series(5001, 1000 + 7 * seed)))
    indices = [s[1][2] for s in saved]
    assert len({tuple(i) for i in indices}) == 3  # three different sample sets
    assert len(list(tmp_path.glob("truth__*.npz"))) == 1
    for path, (s_tr, s_truth, _) in saved:
        got_tr, got_truth = load_trajectory(path)
        _assert_same(got_tr, s_tr)
        _assert_same(got_truth, s_truth)


class _Series:
    """Error series with one maximum at sample ``at`` (what saved_indices keeps besides the stride)."""

    def __init__(self, n: int, at: int):
        e = np.zeros(n)
        e[at] = 1.0
        self.orientation_error = self.angular_momentum_error = self.energy_error = self.position_error = e


def test_shared_rows_are_the_stride_and_the_last_sample():
    index = np.array([0, 7, 14, 15, 21, 28, 30], np.int64)
    assert shared_rows(index).tolist() == [True, True, True, False, True, True, True]
    assert shared_rows(np.array([0], np.int64)).tolist() == [True]


def test_a_run_without_samples(tmp_path):
    """A run that kept no sample (ended before its first) reads back as empty arrays of its shapes."""
    empty = _motion(3, 0.1, 5).take(np.zeros(0, np.int64))
    write_trajectory(tmp_path / "empty.npz", empty, empty, np.zeros(0, np.int64))
    tr, truth = load_trajectory(tmp_path / "empty.npz")
    _assert_same(tr, empty)
    _assert_same(truth, empty)


def test_t_off_the_grid_and_a_truth_at_other_times_are_stored(tmp_path):
    """t is left out only when it is sample_index * dt bit for bit, the truth's t only when it is the run's."""
    tr, truth = _motion(11, 0.1, 5), _motion(11, 0.1, 6)
    bent = Trajectory(tr.t + 1e-3 * np.arange(11) ** 2, tr.position, tr.quaternion_wxyz, tr.linear_velocity,
                      tr.angular_velocity)
    other = Trajectory(truth.t * (1 + 1e-12), truth.position, truth.quaternion_wxyz, truth.linear_velocity,
                       truth.angular_velocity)
    path, (s_tr, s_truth, _) = _save(tmp_path, bent, other)
    with np.load(path) as z:
        layout = json.loads(str(z["layout"][()]))
    assert layout["dt"] is None and "t" in layout["columns"] and "t" in layout["truth"]["columns"]
    got_tr, got_truth = load_trajectory(path)
    _assert_same(got_tr, s_tr)
    _assert_same(got_truth, s_truth)


def test_without_truth_and_hand_made_arrays(tmp_path):
    """A run without a truth has no truth file; arrays format 2 does not hold (not float64) are
    written in format 1, as they are."""
    tr = _motion(30, 0.01, 7)
    path, (s_tr, _, _) = _save(tmp_path, tr, None)
    got, truth = load_trajectory(path)
    _assert_same(got, s_tr)
    assert truth is None and not list(tmp_path.glob("truth__*"))
    ints = Trajectory(np.arange(3), np.zeros((3, 3), int), np.ones((3, 4), int), np.zeros((3, 3), int),
                      np.zeros((3, 3), int))
    write_trajectory(tmp_path / "ints.npz", ints, None, np.arange(3))
    with np.load(tmp_path / "ints.npz") as z:
        assert "layout" not in z.files and z["position"].dtype == int
    _assert_same(load_trajectory(tmp_path / "ints.npz")[0], ints)


def test_format1_on_request(tmp_path):
    """trajectory_format=1 writes one plain npz as earlier releases did (np.load alone reads it)."""
    tr, truth = _motion(30, 0.01, 7), _motion(30, 0.01, 8)
    write_trajectory(tmp_path / "old.npz", tr, truth, np.arange(30), trajectory_format=1)
    with np.load(tmp_path / "old.npz") as z:
        assert "layout" not in z.files and _same(z["truth_quaternion_wxyz"], truth.quaternion_wxyz)
    _assert_same(load_trajectory(tmp_path / "old.npz")[1], truth)
    assert not list(tmp_path.glob("truth__*"))
    with pytest.raises(ValueError, match="trajectory format 3"):
        write_trajectory(tmp_path / "new.npz", tr, truth, np.arange(30), trajectory_format=3)


# --- format 1 (earlier releases): read as before ------------------------------------------------

@pytest.fixture
def old_folder(tmp_path) -> Path:
    out = tmp_path / "old"
    shutil.copytree(GOLDEN, out)
    return out


def _runs(folder: Path) -> list[dict]:
    return [r for r in json.loads((folder / "results.json").read_text())["runs"] if r.get("trajectory")]


def test_format1_files_read_as_their_arrays(old_folder):
    """Every array of a format-1 file, through every reader, is the array np.load gives."""
    for run in _runs(old_folder):
        with np.load(old_folder / run["trajectory"]) as z:
            raw = {k: z[k] for k in z.files}
        assert "layout" not in raw  # the golden files are format 1
        tr, truth = load_trajectory(old_folder / run["trajectory"])
        for f in FIELDS:
            assert _same(getattr(tr, f), raw.get(f))
            if f != "orthonormality_error":
                assert _same(getattr(truth, f), raw["truth_" + f])
        with open_run_trajectory(old_folder, run) as z:
            assert z.format == 1 and sorted(z) == sorted(raw)
            assert all(_same(z[k], raw[k]) for k in raw)


def test_format1_and_format2_give_the_same_arrays_and_figures(old_folder, tmp_path):
    """A format-1 folder rewritten in format 2 loads the same arrays by every name, and the
    report's readers (findings' trajectories, the figures' series) get the same numbers."""
    new = tmp_path / "new"
    shutil.copytree(old_folder, new)
    for run in _runs(old_folder):
        tr, truth = load_trajectory(old_folder / run["trajectory"])
        with np.load(old_folder / run["trajectory"]) as z:
            index = z["sample_index"]
        write_trajectory(new / run["trajectory"], tr, truth, index)
    assert len(list(new.glob("trajectories/1/truth__*.npz"))) == 1  # both runs: dzhanibekov, dt 0.01
    for run in _runs(old_folder):
        with open_run_trajectory(old_folder, run) as a, open_run_trajectory(new, run) as b:
            assert (a.format, b.format) == (1, 2) and sorted(a) == sorted(b)
            assert all(_same(a[k], b[k]) for k in a)
        assert all(_same(x, y) for x, y in zip(rd.trajectory_reader(old_folder)(run), rd.trajectory_reader(new)(run)))
        (sa, ta), (sb, tb) = (rd.SeriesReader(None).read(f / run["trajectory"], run) for f in (old_folder, new))
        for x, y in ((sa, sb), (ta, tb)):
            for k, v in vars(x).items():
                if isinstance(v, np.ndarray):
                    assert _same(v, getattr(y, k)), k


def test_format1_folder_renders_its_report(old_folder):
    """A stored results folder of an earlier release still renders (report.md from its files)."""
    from freebody.cli import main

    assert main(["report", str(old_folder), "--markdown-only", "--quiet"]) == 0
    assert "dzhanibekov" in (old_folder / "report.md").read_text()


# --- what is refused ------------------------------------------------------------------------------

def _layout_of(path: Path) -> dict:
    with np.load(path) as z:
        return json.loads(str(z["layout"][()]))


def _rewrite(path: Path, **layout) -> None:
    """The file at ``path`` with its layout's keys replaced."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["layout"] = np.array(json.dumps({**json.loads(str(arrays["layout"][()])), **layout}))
    write_npz_atomic(path, arrays)


def test_a_newer_format_says_so(tmp_path):
    path, _ = _save(tmp_path, _motion(5, 0.1, 8), None)
    _rewrite(path, trajectory_format=3)
    with pytest.raises(InputError, match="trajectory format 3: this freebody reads formats 1, 2"):
        load_trajectory(path)


def test_a_truth_file_is_a_name_beside_the_run(tmp_path):
    """The truth file a run file names is a plain name (no path), read beside it, through the same
    checks as the run's file; a run file naming another path is refused, a missing one says which."""
    path, _ = _save(tmp_path, _motion(5, 0.1, 8), _motion(5, 0.1, 9))
    good = _layout_of(path)["truth"]
    _rewrite(path, truth={**good, "file": "../truth__000000000000.npz"})
    with pytest.raises(InputError, match="truth entry"):
        load_trajectory(path)
    _rewrite(path, truth=good)
    (tmp_path / good["file"]).rename(tmp_path / "elsewhere.npz")
    with pytest.raises(InputError, match=f"its truth file {good['file']}") as e:
        load_trajectory(path)
    assert e.value.reason.startswith(f"its truth file {good['file']}: ")  # what a figure's note says
    (tmp_path / good["file"]).symlink_to(tmp_path / "elsewhere.npz")
    with pytest.raises(InputError, match="symbolic link"):
        load_trajectory(path)
    with open_trajectory(path, 10 ** 6) as z:  # the run's own arrays read without its truth file
        assert len(z["t"]) == 5


def test_a_damaged_file_is_refused_not_a_crash(tmp_path):
    path, _ = _save(tmp_path, _motion(5, 0.1, 8), None)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    write_npz_atomic(path, {**arrays, "samples": arrays["samples"][:-8]})
    with pytest.raises(InputError, match="not a trajectory file"):
        load_trajectory(path)


# --- the output folder: truth files live and go with their runs ---------------------------------

def test_truth_files_are_deleted_with_the_runs_that_name_them(tmp_path):
    from freebody.results.document import results_document

    out = tmp_path / "out"
    folders = []
    for _ in range(2):
        with output_lock(out):
            folder = OutputFolder(out)
            _save(folder.trajectory_dir, _motion(5, 0.1, 8), _motion(5, 0.1, 9))
            run = {"case": "c", "engine": "e", "integrator": "i", "dt": 0.1, "status": "ok",
                   "trajectory": folder.relative("run0__" + "0" * 12 + ".npz")}
            folder.publish(results_document([run], {}))
            folders.append(folder.trajectory_dir)
    assert not folders[0].exists()  # the first invocation's runs and truth file: all gone
    assert sorted(p.name.split("__")[0] for p in folders[1].iterdir()) == ["run0", "truth"]
    assert zipfile.is_zipfile(next(folders[1].glob("truth__*.npz")))
