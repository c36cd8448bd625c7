"""Case files a newcomer can write (issue 21, item 4): optional keys default, dt and duration may
come from the command line, ``freebody new-case`` prints a template that runs, and the key table
of docs/case-files.md is the parser's (neither can gain or lose a key alone)."""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

import freebody
from freebody.cli import main
from freebody.errors import InputError
from freebody.results.document import SCHEMA_VERSION
from freebody.input.casefile import (DEFAULTS, REQUIRED_TOP_KEYS, SECTIONS, TOP_KEYS, case_template,
                                     defaulted_keys, load_case)

DOC = Path(__file__).resolve().parents[1] / "docs" / "case-files.md"
BARE = 'name = "bare"\n[body]\nmass = 1.0\ninertia = [[1, 0, 0], [0, 2, 0], [0, 0, 3]]\n'
"""The smallest file that loads: a name and a body (at rest; no dt, no duration)."""
RUN = ["--engine", "reference", "--integrator", "rk4", "--quiet", "--no-report"]


def _write(tmp_path: Path, text: str, name: str = "case.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _run(tmp_path: Path, path: Path, *options: str) -> int:
    return main(["run", str(path), *RUN, "--out", str(tmp_path / "out"), *options])


def _one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("freebody: error: "), err
    return lines[0]


# --- docs/case-files.md ---------------------------------------------------------------------------

def _doc_section(title: str) -> str:
    text = DOC.read_text()
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end >= 0 else None]


def _doc_key_rows() -> dict[tuple[str, str], dict[str, str]]:
    """(section, key) -> the row of the "Every key" table (section "" for the top level)."""
    lines = [ln for ln in _doc_section("Every key").splitlines() if ln.startswith("|")]
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    rows = {}
    for ln in lines[2:]:  # after the header and its --- line
        row = dict(zip(header, (c.strip() for c in ln.strip().strip("|").split("|"))))
        section = row["section"].strip("`[]").replace("top level", "")
        key = row["key"].strip("`")
        assert (section, key) not in rows, f"{section}.{key} is in the table twice"
        rows[(section, key)] = row
    return rows


def _parser_keys() -> set[tuple[str, str]]:
    return ({("", k) for k in TOP_KEYS - SECTIONS.keys()}
            | {(section, k) for section, keys in SECTIONS.items() for k in keys})


def test_every_key_of_the_doc_table_is_a_parser_key_and_back():
    doc, parser = set(_doc_key_rows()), _parser_keys()
    assert doc - parser == set(), "documented but unknown to the parser"
    assert parser - doc == set(), "known to the parser but not documented"
    assert SECTIONS.keys() <= TOP_KEYS


def test_the_doc_table_gives_every_default_and_required_key():
    rows = _doc_key_rows()
    for dotted, value in DEFAULTS.items():
        section, _, key = dotted.rpartition(".")
        row = rows[(section, key)]
        assert row["required"] == "optional", dotted
        assert tomllib.loads("v = " + row["default"].strip("`"))["v"] == value, dotted
    required = {k for (section, k), row in rows.items() if not section and row["required"] == "required"}
    assert required == REQUIRED_TOP_KEYS - SECTIONS.keys()


def test_the_doc_minimal_example_is_what_new_case_minimal_prints():
    block = re.search(r"## The minimal case\n\n```toml\n(.*?)```", DOC.read_text(), re.S).group(1)
    assert block == case_template("my-first-case", minimal=True)
    assert len(block.splitlines()) == 5


# --- the minimal case, defaults --------------------------------------------------------------------

def test_the_five_line_minimal_case_loads_and_runs(tmp_path, capsys):
    p = _write(tmp_path, case_template("first", minimal=True))
    pb = load_case(p)
    assert pb.dts == (0.01,) and pb.duration == 10.0
    assert np.array_equal(pb.initial.angular_velocity, [0.01, 5.0, 0.0])
    assert _run(tmp_path, p, "--duration", "0.1") == 0, capsys.readouterr().err


def test_left_out_keys_take_the_documented_defaults(tmp_path):
    pb = load_case(_write(tmp_path, BARE))
    assert pb.description == DEFAULTS["description"] == ""
    assert np.array_equal(pb.initial.position, DEFAULTS["initial.position"])
    assert np.array_equal(pb.initial.quaternion_wxyz, DEFAULTS["initial.orientation"])
    assert np.array_equal(pb.initial.linear_velocity, DEFAULTS["initial.linear_velocity"])
    assert np.array_equal(pb.initial.angular_velocity, DEFAULTS["initial.angular_velocity"])
    assert np.array_equal(pb.gravity, np.zeros(3))  # no [world]: no gravity
    assert pb.dts == () and pb.duration is None and pb.duration_steps is None


def test_defaulted_keys_records_what_a_case_left_out(tmp_path):
    assert defaulted_keys(_write(tmp_path, BARE)) == list(DEFAULTS)
    minimal = _write(tmp_path, case_template("m", minimal=True), "minimal.toml")
    assert defaulted_keys(minimal) == ["description", "initial.position", "initial.orientation",
                                       "initial.linear_velocity", "world.gravity"]
    assert defaulted_keys(_write(tmp_path, case_template("t"), "template.toml")) == []
    with_gravity = _write(tmp_path, BARE + "[world]\ngravity = [0, 0, -9.81]\n", "g.toml")
    assert "world.gravity" not in defaulted_keys(with_gravity)
    empty_world = _write(tmp_path, BARE + "[world]\n", "w.toml")
    assert "world.gravity" in defaulted_keys(empty_world)
    assert np.array_equal(load_case(empty_world).gravity, np.zeros(3))
    assert defaulted_keys("dzhanibekov") == []  # a bundled case, by name
    assert defaulted_keys(tomllib.loads(BARE)) == list(DEFAULTS)  # TOML data


# --- dt and duration from the command line ----------------------------------------------------------

def test_dt_and_duration_may_come_from_the_command_line(tmp_path, capsys):
    p = _write(tmp_path, BARE)
    assert _run(tmp_path, p, "--dt", "0.01", "--duration", "0.05") == 0, capsys.readouterr().err
    only_duration = _write(tmp_path, BARE + "", "d.toml")
    only_duration.write_text(BARE.replace("[body]", "duration = 0.05\n[body]"))
    assert _run(tmp_path, only_duration, "--dt", "0.01") == 0, capsys.readouterr().err


@pytest.mark.parametrize("text,options,key,option", [
    (BARE, ["--duration", "0.1"], "dt", "--dt"),
    (BARE.replace("[body]", "dt = 0.01\n[body]"), [], "duration", "--duration"),
    (BARE, [], "dt", "--dt"),
], ids=["no_dt", "no_duration", "neither"])
def test_a_missing_dt_or_duration_is_one_line_naming_the_file_and_key(tmp_path, capsys, text, options,
                                                                       key, option):
    p = _write(tmp_path, text)
    line = _one_line_error(capsys, _run(tmp_path, p, *options))
    assert line.startswith(f"freebody: error: {p}: {key}: missing; "), line
    assert option in line and "in the case file" in line
    assert not (tmp_path / "out" / "results.json").exists()


def test_the_api_names_a_case_without_dt(tmp_path):
    with pytest.raises(InputError, match=r"^case 'bare': dt: missing; "):
        freebody.run_case(str(_write(tmp_path, BARE)), integrator="rk4", duration=0.05)
    out = freebody.run_case(str(_write(tmp_path, BARE)), integrator="rk4", dt=0.01, duration=0.05)
    assert out.result.status == "ok"


def test_duration_and_duration_steps_together_are_still_an_error(tmp_path, capsys):
    p = _write(tmp_path, BARE.replace("[body]", "dt = 0.01\nduration = 1.0\nduration_steps = 3\n[body]"))
    line = _one_line_error(capsys, _run(tmp_path, p))
    assert f"{p}: duration: give exactly one of duration (s) and duration_steps, not both" in line


@pytest.mark.parametrize("old,new,message", [
    ("mass = 1.0", "mas = 1.0", "body.mas: unknown key (did you mean 'mass'?); allowed: density, inertia, mass, "
                                "mesh, shape, size"),
    ('name = "bare"', 'name = "bare"\nduraton = 1.0', "duraton: unknown key (did you mean 'duration'?); allowed: "
     "body, description, dt, duration, duration_steps, initial, loads, name, world"),
    ("[body]", "[initial]\nangular_velocty = [0, 1, 0]\n[body]", "initial.angular_velocty: unknown key (did you "
     "mean 'angular_velocity'?); allowed: angular_velocity, linear_velocity, orientation, position"),
    ("[body]", "[world]\ngravty = [0, 0, -9.81]\n[body]", "world.gravty: unknown key (did you mean 'gravity'?); "
     "allowed: gravity"),
    ("mass = 1.0\n", "", "body.mass: missing required key"),
    ('name = "bare"\n', "", "name: missing required key"),
], ids=["body_typo", "top_typo", "initial_typo", "world_typo", "no_mass", "no_name"])
def test_typos_and_missing_required_keys_keep_their_messages(tmp_path, capsys, old, new, message):
    p = _write(tmp_path, BARE.replace(old, new, 1))
    line = _one_line_error(capsys, _run(tmp_path, p, "--dt", "0.01", "--duration", "0.05"))
    assert line == f"freebody: error: {p}: {message}"


# --- freebody new-case ----------------------------------------------------------------------------

def _template_keys(text: str) -> set[tuple[str, str]]:
    """(section, key) of every assignment in the template, commented out or not."""
    keys, section = set(), ""
    for line in text.splitlines():
        line = re.sub(r"^#\s?", "", line).strip()
        header = re.match(r"^\[\[?(\w+)\]\]?", line)
        if header:
            section = header.group(1)
        elif m := re.match(r"^(\w+) = ", line):
            keys.add((section, m.group(1)))
    return keys


def test_the_template_lists_every_key_and_runs(tmp_path, capsys):
    assert main(["new-case", "tmpl", "--out", str(tmp_path / "tmpl.toml")]) == 0
    p = tmp_path / "tmpl.toml"
    assert p.read_text() == case_template("tmpl")
    assert _template_keys(p.read_text()) == _parser_keys()
    assert load_case(p).name == "tmpl"
    assert _run(tmp_path, p, "--duration", "0.1") == 0, capsys.readouterr().err


def test_new_case_prints_the_template_and_the_minimal_file(capsys):
    assert main(["new-case", "spin"]) == 0
    assert capsys.readouterr().out == case_template("spin")
    assert main(["new-case", "spin", "--minimal"]) == 0
    out = capsys.readouterr().out
    assert out == case_template("spin", minimal=True) and len(out.splitlines()) == 5
    assert tomllib.loads(out)["name"] == "spin"


def test_new_case_names_the_case_after_the_out_file(tmp_path, capsys):
    assert main(["new-case", "--minimal", "--out", str(tmp_path / "spinner.toml")]) == 0
    assert load_case(tmp_path / "spinner.toml").name == "spinner"


def test_new_case_never_overwrites_a_file(tmp_path, capsys):
    p = _write(tmp_path, "mine\n")
    line = _one_line_error(capsys, main(["new-case", "x", "--out", str(p)]))
    assert str(p) in line and "already there" in line
    assert p.read_text() == "mine\n"
    line = _one_line_error(capsys, main(["new-case", "x", "--out", str(tmp_path)]))
    assert "a folder is already there" in line


def test_new_case_refuses_a_name_no_case_may_have(capsys):
    line = _one_line_error(capsys, main(["new-case", "bad\x1b[31mname"]))
    assert "name: must be printable" in line and "\x1b" not in line
    _one_line_error(capsys, main(["new-case", "n" * 101]))


def test_a_name_with_quotes_and_backslashes_round_trips(tmp_path):
    name = 'say "hi" \\ bye'
    assert load_case(_write(tmp_path, case_template(name, minimal=True))).name == name


def test_the_defaults_a_case_used_are_in_results_and_report(tmp_path):
    """No [world] means no gravity: results.json (schema 3, cases.<name>.defaults) and the report say so."""
    import json

    from freebody.cli import main

    case = tmp_path / "bare.toml"
    case.write_text('name = "bare"\ndt = 0.01\nduration = 0.1\n'
                    'body = { mass = 1.0, inertia = [[1, 0, 0], [0, 2, 0], [0, 0, 3]] }\n')
    assert main(["run", str(case), "--engine", "reference", "--integrator", "rk4", "--out", str(tmp_path / "o"),
                 "--quiet"]) == 0
    doc = json.loads((tmp_path / "o" / "results.json").read_text())
    assert doc["schema_version"] == SCHEMA_VERSION == 7
    assert "world.gravity" in doc["cases"]["bare"]["defaults"]
    assert "initial.angular_velocity" in doc["cases"]["bare"]["defaults"]
    assert "no [world]: no gravity" in (tmp_path / "o" / "report.md").read_text()
