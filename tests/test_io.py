"""The shared pieces every part of freebody writes and shows through: atomic writes with one
permission rule (``freebody.results.io``), the missing-number rule (``freebody.numbers``), the
results-document header, the progress display and the C-level output capture."""
from __future__ import annotations

import io
import json
import math
import os
import stat

import numpy as np
import pytest

from freebody.adapters.capture import FdCapture, capture_output
from freebody.numbers import finite_or_none
from freebody.results.document import SCHEMA_VERSION, document_header, results_document
from freebody.results.io import (is_temporary, json_safe, read_json, write_json_atomic, write_npz_atomic,
                                 write_text_atomic)
from freebody.errors import InputError
from freebody.run.progress import ProgressDisplay


def _write_all(folder):
    write_text_atomic(folder / "a.txt", "text\n")
    write_json_atomic(folder / "sub" / "b.json", {"x": 1.0})
    write_npz_atomic(folder / "c.npz", {"t": np.arange(3.0)})
    return [folder / "a.txt", folder / "sub" / "b.json", folder / "c.npz"]


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_written_files_get_the_mode_of_a_plain_open(tmp_path, mask):
    old = os.umask(mask)
    try:
        paths = _write_all(tmp_path)
        with open(tmp_path / "plain", "w"):
            pass
    finally:
        os.umask(old)
    want = stat.S_IMODE(os.stat(tmp_path / "plain").st_mode)
    assert want == 0o666 & ~mask
    assert [stat.S_IMODE(os.stat(p).st_mode) for p in paths] == [want] * 3
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "b.json", "c.npz", "plain", "sub"]


def test_json_is_sorted_with_nulls_for_non_finite_numbers(tmp_path):
    write_json_atomic(tmp_path / "d.json", {"b": np.float32(2.0), "a": [np.nan, np.inf, 1, np.int64(3)]})
    text = (tmp_path / "d.json").read_text()
    assert text.endswith("\n") and text.index('"a"') < text.index('"b"')
    assert json.loads(text) == {"a": [None, None, 1, 3], "b": 2.0}
    assert read_json(tmp_path / "d.json", "d") == json.loads(text)


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    write_text_atomic(tmp_path / "r.json", "old")
    with pytest.raises(AttributeError):  # fails while writing the temporary file
        write_text_atomic(tmp_path / "r.json", 5)
    assert (tmp_path / "r.json").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_temporary_file_names():
    assert is_temporary(".case__mujoco__Euler__float64__dt0.01.npz.ab_d3f9z.tmp")
    assert not is_temporary("case__mujoco__Euler__float64__dt0.01.npz")
    assert not is_temporary("results.json")


def test_read_json_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="where: no such file"):
        read_json(tmp_path / "missing.json", "where")
    (tmp_path / "bad.json").write_text("{runs: ")
    with pytest.raises(InputError, match=r"bad: not valid JSON: .* \(line 1, column 2\)"):
        read_json(tmp_path / "bad.json", "bad")


@pytest.mark.parametrize("x, want", [(1.5, 1.5), (2, 2.0), (np.float32(0.5), 0.5), (np.int64(4), 4.0),
                                     (math.nan, None), (-math.inf, None), (None, None), ("1", None),
                                     (True, None), (np.nan, None)])
def test_finite_or_none(x, want):
    got = finite_or_none(x)
    assert got == want and (got is None or type(got) is float)


def test_json_safe_keeps_ints_and_bools():
    assert json_safe({"n": 3, "ok": True, "x": (np.bool_(False), math.nan)}) == {"n": 3, "ok": True,
                                                                                 "x": [False, None]}


def test_every_document_opens_with_the_same_header():
    head = document_header(7, {"mujoco": "3.3"}, kind="k")
    assert list(head) == ["schema_version", "freebody_version", "created", "platform", "engines", "kind"]
    assert head["schema_version"] == 7 and "engines" not in document_header(1)
    doc = results_document([], {"reference": "x"})
    assert list(doc)[:5] == list(head)[:5] and doc["schema_version"] == SCHEMA_VERSION
    assert doc["incomplete"] is False and doc["runs"] == []


class _Tty(io.StringIO):
    def isatty(self):
        return True


def test_progress_on_a_terminal_rewrites_one_line():
    out = _Tty()
    bar = ProgressDisplay(2, "bodies", stream=out)
    bar.update("first")
    bar.update("second")  # the last: shown whatever the throttle, and ended
    bar.note("done")
    lines = out.getvalue().split("\r\033[K")
    assert lines[0] == "" and lines[1].startswith("[1/2 bodies]  50% ") and lines[1].endswith("ETA --  first")
    assert lines[2].startswith("[2/2 bodies] 100% ") and lines[2].endswith("ETA 0:00  second\ndone\n")


def test_progress_in_a_log_writes_the_first_every_nth_line_and_the_last():
    out = io.StringIO()
    bar = ProgressDisplay(5, "", stream=out, every=2)
    for i in range(5):
        bar.update(f"run {i}")
    lines = out.getvalue().splitlines()
    assert [ln.split()[0] for ln in lines] == ["[1/5]", "[2/5]", "[4/5]", "[5/5]"]
    assert lines[1].endswith("  run 1") and "\r" not in out.getvalue()
    quiet = io.StringIO()
    ProgressDisplay(3, stream=quiet, enabled=False).update("x")
    assert quiet.getvalue() == ""


def test_fd_capture_is_readable_while_capturing_and_nests(capfd):
    with capture_output() as outer:
        with FdCapture((2,)) as inner:
            assert not inner.has_output()
            os.write(2, b"\x1b[31mwarning\x1b[0m  \n\n")
            assert inner.has_output() and inner.read_lines() == ["\x1b[31mwarning\x1b[0m"]
            os.write(1, b"to stdout\n")
        assert inner.lines == ["\x1b[31mwarning\x1b[0m"]
        os.write(2, b"after\n")
    assert (outer.lines, outer.total) == (["to stdout", "after"], 2)
    assert capfd.readouterr() == ("", "")
