"""The adapter contract as documented is the contract as declared.

docs/adapters.md's "Members" table is checked against :class:`freebody.adapters.base.Adapter`:
every public member of ``Adapter`` (class attribute, classmethod, method, instance attribute set
by the constructor) has a row and every row names a real member of the kind the row says, with
the parameters it lists; a literal default in the table is the actual one; "required" means
abstract (or annotated without a value).  The "EngineEntry" table is checked against
:class:`~freebody.adapters.base.EngineEntry`'s fields and defaults, the "SteppedAdapter" table
against :class:`~freebody.adapters.base.SteppedAdapter`.  And no adapter shipped here (the
built-ins, the worked example, the fake engines) overrides what the docs say not to override,
or declares a public class attribute the contract does not have (one the harness cannot read).
"""
from __future__ import annotations

import ast
import importlib.util
import inspect
import re
import textwrap
from pathlib import Path

import pytest

from freebody.adapters.base import ENGINES, Adapter, EngineEntry, SteppedAdapter

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "adapters.md"
KINDS = ("class attribute", "classmethod", "method", "instance attribute", "provided")
REQUIRED = "required"
# members the harness calls and an adapter must not override (besides __init__)
NOT_FOR_OVERRIDING_KIND = "provided"


# --- reading the docs ---------------------------------------------------------------------------

def _section(text: str, heading: str) -> str:
    """The text under a ``### heading`` line, up to the next heading of any level."""
    m = re.search(rf"^### {re.escape(heading)}\n(.*?)(?=^#{{1,3}} )", text, re.S | re.M)
    assert m, f"docs/adapters.md has no section '### {heading}'"
    return m.group(1)


def _cells(line: str) -> list[str]:
    """The cells of a Markdown table row (``\\|`` is a pipe inside a cell)."""
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def _table(section: str, header: tuple[str, ...]) -> list[list[str]]:
    """The rows of the first table in ``section`` whose header is ``header``."""
    lines = section.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("|") and tuple(_cells(line)) == header:
            rows = []
            for row in lines[i + 2:]:
                if not row.startswith("|"):
                    break
                rows.append(_cells(row))
            assert rows, f"empty table {header}"
            return rows
    raise AssertionError(f"no table with the header {header} in the section")


def _code(cell: str) -> str:
    """The first ``code`` span of a cell, or ''."""
    m = re.search(r"`([^`]*)`", cell)
    return m.group(1) if m else ""


def _signature(cell: str) -> tuple[str, tuple[str, ...] | None]:
    """``advance(steps)`` -> ("advance", ("steps",)); ``name`` -> ("name", None)."""
    text = _code(cell)
    m = re.fullmatch(r"([A-Za-z_]\w*)(?:\((.*)\))?", text)
    assert m, f"the member cell {cell!r} is not `name` or `name(params)`"
    params = None if m.group(2) is None else tuple(p.strip() for p in m.group(2).split(",") if p.strip())
    return m.group(1), params


def members_table() -> dict[str, dict]:
    """name -> {"params", "kind", "default"} of the Members table."""
    rows = _table(_section(DOC.read_text(), "Members"), ("member", "kind", "default", "meaning"))
    out = {}
    for member, kind, default, _meaning in rows:
        name, params = _signature(member)
        assert name not in out, f"{name} has two rows"
        out[name] = {"params": params, "kind": kind, "default": default}
    return out


# --- reading Adapter ----------------------------------------------------------------------------

def _init_assignments(cls: type) -> dict[str, ast.expr]:
    """``self.X = value`` in ``cls.__init__``: X -> the value's AST."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls.__init__)))
    out = {}
    for node in ast.walk(tree):
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for t in targets:
            if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) and t.value.id == "self":
                out[t.attr] = node.value
    return out


def declared_members(cls: type = Adapter) -> dict[str, str]:
    """Public members of ``cls`` (its own, not its bases') -> their kind."""
    out = {}
    for name, annotation in vars(cls).get("__annotations__", {}).items():
        if "ClassVar" in str(annotation) and not name.startswith("_"):
            out[name] = "class attribute"
    for name, value in vars(cls).items():
        if name.startswith("_") or name in out:
            continue
        if isinstance(value, classmethod):
            out[name] = "classmethod"
        elif inspect.isfunction(value):
            out[name] = "method"
    if "__init__" in vars(cls):
        for name in _init_assignments(cls):
            if not name.startswith("_"):
                out.setdefault(name, "instance attribute")
    return out


def _is_abstract(cls: type, name: str) -> bool:
    return name in cls.__abstractmethods__


def _params(cls: type, name: str) -> tuple[str, ...]:
    fn = inspect.getattr_static(cls, name)
    fn = fn.__func__ if isinstance(fn, classmethod) else fn
    return tuple(inspect.signature(fn).parameters)[1:]  # without self / cls


def _literal(cell: str):
    """The Python literal of a default cell (its code span), or raise ValueError (prose)."""
    try:
        return ast.literal_eval(_code(cell))
    except SyntaxError as e:
        raise ValueError(f"{cell!r} is no literal") from e


# --- the checks ---------------------------------------------------------------------------------

def test_every_public_member_of_adapter_is_in_the_table_and_every_row_is_a_member():
    table, declared = members_table(), declared_members(Adapter)
    missing = sorted(set(declared) - set(table))
    unknown = sorted(set(table) - set(declared))
    assert not missing, f"public members of Adapter missing from docs/adapters.md 'Members': {missing}"
    assert not unknown, f"rows of docs/adapters.md 'Members' that are no member of Adapter: {unknown}"


def test_each_row_says_the_members_kind_and_parameters():
    declared = declared_members(Adapter)
    for name, row in members_table().items():
        assert row["kind"] in KINDS, f"{name}: kind {row['kind']!r} is none of {KINDS}"
        actual = declared[name]
        if row["kind"] == NOT_FOR_OVERRIDING_KIND:
            assert actual in ("method", "classmethod") and not _is_abstract(Adapter, name), name
        else:
            assert row["kind"] == actual, f"{name} is a {actual}, the docs say {row['kind']}"
        if actual in ("method", "classmethod"):
            assert row["params"] == _params(Adapter, name), (
                f"{name}: the docs list the parameters {row['params']}, the signature has "
                f"{_params(Adapter, name)}")
        else:
            assert row["params"] is None, f"{name} is an attribute, written as a call in the docs"


def test_required_means_abstract_and_literal_defaults_are_the_actual_ones():
    init = _init_assignments(Adapter)
    for name, row in members_table().items():
        required = row["default"] == REQUIRED
        if row["kind"] == "class attribute":
            has_value = name in vars(Adapter)
            assert required != has_value, (f"{name}: the docs say {row['default']!r}, Adapter "
                                           f"{'gives a default' if has_value else 'gives none'}")
            if not required:
                assert _literal(row["default"]) == getattr(Adapter, name), (
                    f"{name}: the docs' default {row['default']} is not Adapter's {getattr(Adapter, name)!r}")
        elif row["kind"] in ("method", "classmethod"):
            assert required == _is_abstract(Adapter, name), f"{name}: required in the docs iff abstract"
        elif row["kind"] == "instance attribute":
            assert not required, f"{name}: the constructor sets it"
            try:
                doc_value = _literal(row["default"])
            except ValueError:  # prose: "set by the constructor"
                continue
            assert isinstance(init[name], ast.Constant | ast.Dict | ast.Tuple | ast.List), (
                f"{name}: the docs give the literal {row['default']}, the constructor computes it")
            assert doc_value == ast.literal_eval(init[name]), (
                f"{name}: the docs' default {row['default']} is not the constructor's {ast.unparse(init[name])}")


def test_the_engine_entry_table_is_its_fields_with_their_defaults():
    rows = _table(_section(DOC.read_text(), "`EngineEntry`"), ("field", "default", "meaning"))
    names = [_code(r[0]) for r in rows]
    assert names == list(EngineEntry._fields), (
        f"docs/adapters.md 'EngineEntry' lists {names}, EngineEntry has {list(EngineEntry._fields)}")
    for (_, default, _), name in zip(rows, names):
        if name in EngineEntry._field_defaults:
            assert default != REQUIRED and _literal(default) == EngineEntry._field_defaults[name], (
                f"EngineEntry.{name}: the docs' default {default} is not {EngineEntry._field_defaults[name]!r}")
        else:
            assert default == REQUIRED, f"EngineEntry.{name} has no default, the docs say {default}"


def test_the_stepped_adapter_table_is_what_it_adds():
    rows = _table(_section(DOC.read_text(), "`SteppedAdapter`"), ("method", "meaning"))
    table = dict(_signature(r[0]) for r in rows)
    own = {n: k for n, k in declared_members(SteppedAdapter).items() if n not in declared_members(Adapter)}
    assert set(table) == set(own), f"docs: {sorted(table)}, SteppedAdapter adds {sorted(own)}"
    for name, params in table.items():
        assert params == _params(SteppedAdapter, name), name


def _shipped_adapter_modules() -> list[Path]:
    """The source files of the built-in adapters, the worked example's and the fake engine's."""
    paths = [Path(importlib.util.find_spec(e.module).origin) for e in ENGINES.values()]
    paths += sorted((ROOT / "examples").rglob("adapter.py")) + sorted((ROOT / "tests" / "fake_engines").rglob("*.py"))
    return paths


# Public class attributes of shipped adapters that are not the contract's, each with its reason.
OWN_CLASS_ATTRIBUTES = {
    "BatchingAdapter.batch_calls": "the fake engine's record of its simulate_batch calls, read by its tests",
}


def _adapter_classes(tree: ast.Module) -> list[ast.ClassDef]:
    """The adapter classes of a module: subclasses of Adapter, SteppedAdapter, a built-in adapter
    class, or another adapter class of the module."""
    known = {"Adapter", "SteppedAdapter"} | {e.cls for e in ENGINES.values()}
    classes = [n for n in tree.body if isinstance(n, ast.ClassDef)]
    adapters: list[ast.ClassDef] = []
    for _ in classes:
        for c in classes:
            bases = {getattr(b, "id", getattr(b, "attr", "")) for b in c.bases}
            if c not in adapters and bases & (known | {a.name for a in adapters}):
                adapters.append(c)
    return adapters


@pytest.mark.parametrize("path", _shipped_adapter_modules(), ids=lambda p: p.name)
def test_no_shipped_adapter_overrides_what_the_harness_provides(path):
    provided = {n for n, row in members_table().items() if row["kind"] == NOT_FOR_OVERRIDING_KIND}
    provided.add("__init__")
    tree = ast.parse(path.read_text(), filename=str(path))
    found = [f"{c.name}.{f.name} (line {f.lineno})" for c in _adapter_classes(tree)
             for f in c.body if isinstance(f, ast.FunctionDef) and f.name in provided]
    assert not found, f"{path.name} overrides what the docs say not to: {found}"


@pytest.mark.parametrize("path", _shipped_adapter_modules(), ids=lambda p: p.name)
def test_no_shipped_adapter_declares_a_class_attribute_the_contract_does_not_have(path):
    """A public class attribute outside the contract is one the harness cannot read (dead, as
    ``reference_maps`` was) or reads around the contract: declare it on Adapter, or make it private."""
    contract = set(declared_members(Adapter)) | set(declared_members(SteppedAdapter))
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for c in _adapter_classes(tree):
        for node in c.body:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
            for t in targets:
                name = getattr(t, "id", "")
                if name and not name.startswith("_") and name not in contract \
                        and f"{c.name}.{name}" not in OWN_CLASS_ATTRIBUTES:
                    found.append(f"{c.name}.{name} (line {node.lineno})")
    assert not found, f"{path.name}: class attributes outside the adapter contract: {found}"
