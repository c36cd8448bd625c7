"""The import layers, read from the source (AST, nothing imported):

- ``reference_impl/`` (``freebody.reference_impl``) imports the standard library, numpy, scipy,
  numba and itself: no adapter, no harness module, no engine.
- ``adapters/`` (``freebody.adapters``) imports, of freebody, only ``reference_impl``, its own
  folder and the harness's leaf modules in :data:`ADAPTER_HARNESS_IMPORTS` (third-party engines
  are theirs to import).
- A module that reaches outside its own folder does so absolutely (``from freebody.tolerances
  import X``, never ``from ..tolerances import X``): ``adapters/`` and ``reference_impl/`` are
  installed as ``freebody.adapters`` and ``freebody.reference_impl`` but are top-level folders of
  the tree, so a ``..`` climbs out of the folder a reader sees.
- Nobody imports another module's ``_private`` names (``from m import _x``, or ``m._x`` on an
  imported module), anywhere in freebody/, adapters/, reference_impl/; tests are exempt.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# package -> folder (pyproject.toml's package-dir)
SOURCE_ROOTS = {"freebody": ROOT / "freebody", "freebody.adapters": ROOT / "adapters",
                "freebody.reference_impl": ROOT / "reference_impl"}

# What reference_impl may import besides itself and the standard library: the numerical stack.
REFERENCE_IMPL_THIRD_PARTY = frozenset({"numpy", "scipy", "numba"})
# The freebody modules outside reference_impl and adapters that an adapter may import, and why:
ADAPTER_HARNESS_IMPORTS = {
    "freebody": "the package itself, for __version__ (the reference engine's version)",
    "freebody.tolerances": "the harness's named constants (a leaf module, imports nothing)",
    "freebody.numbers": "finite-number checks shared with the case reader (a leaf module)",
    "freebody.errors": "the exception types the harness catches (a leaf module)",
}

# Private cross-module imports tolerated while their modules were reworked (issue 27), as
# (importing module, imported module, name).  Empty now, and it only shrinks: never add an entry
# (make the name public); test_the_allowlist_holds_only_live_offenders fails on a stale one.
PRIVATE_IMPORT_ALLOWLIST: frozenset[tuple[str, str, str]] = frozenset()


def _module_files() -> dict[str, Path]:
    """Every module of the three source folders: dotted name -> file."""
    out = {}
    for package, folder in SOURCE_ROOTS.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([package, *parts])
            # a subfolder of freebody/ that is another source root's package is not one (none is)
            out.setdefault(name, path)
    return out


MODULES = _module_files()


def _package_of(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _absolute(module: str, path: Path, node: ast.ImportFrom) -> str:
    """The absolute module a ``from ... import`` names."""
    if not node.level:
        return node.module or ""
    base = _package_of(module, path).split(".")
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(module: str, path: Path):
    """(imported module, names imported from it or None, node) for every import of the file,
    those inside functions included."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node
        elif isinstance(node, ast.ImportFrom):
            yield _absolute(module, path, node), [a.name for a in node.names], node


def _where(path: Path, node: ast.AST) -> str:
    try:
        shown = path.relative_to(ROOT)
    except ValueError:  # a planted file of the tests below
        shown = path
    return f"{shown}:{node.lineno}"


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _top(name: str) -> str:
    return name.partition(".")[0]


def _in_project(name: str) -> bool:
    return name == "freebody" or name.startswith("freebody.")


def _layer(module: str) -> str:
    for package in ("freebody.reference_impl", "freebody.adapters"):
        if module == package or module.startswith(package + "."):
            return package
    return "freebody"


# --- the rules, each a function of the source so that the tests below can plant a violation ------

def reference_impl_violations(module: str, path: Path) -> list[str]:
    out = []
    for target, _names, node in _imports(module, path):
        if _in_project(target):
            ok = _layer(target) == "freebody.reference_impl"
        else:
            ok = _top(target) in REFERENCE_IMPL_THIRD_PARTY or _top(target) in sys.stdlib_module_names
        if not ok:
            out.append(f"{_where(path, node)} imports {target}")
    return out


def adapter_violations(module: str, path: Path) -> list[str]:
    out = []
    for target, _names, node in _imports(module, path):
        if not _in_project(target) or _layer(target) in ("freebody.reference_impl", "freebody.adapters"):
            continue
        if target not in ADAPTER_HARNESS_IMPORTS:
            out.append(f"{_where(path, node)} imports the harness module {target}")
    return out


def climbing_imports(module: str, path: Path) -> list[str]:
    """``from ..x import`` in adapters/ or reference_impl/ (a relative import out of the folder)."""
    out = []
    for _target, _names, node in _imports(module, path):
        if isinstance(node, ast.ImportFrom) and node.level > 1:
            out.append(f"{_where(path, node)} climbs out of its folder "
                       f"(from {'.' * node.level}{node.module or ''} import ...): import "
                       f"{'.'.join(['freebody', *filter(None, [node.module])])} absolutely")
    return out


def private_imports(module: str, path: Path) -> list[tuple[str, str, str, int]]:
    """(module, imported module, private name, line) for every private name of another project
    module this file imports or reads off an imported project module."""
    out = []
    module_aliases: dict[str, str] = {}  # local name -> the project module it is bound to
    for target, names, node in _imports(module, path):
        if not _in_project(target):
            continue
        if names is None:  # import freebody.x.y [as z]
            for alias in node.names:
                if alias.asname:
                    module_aliases[alias.asname] = alias.name
            continue
        for alias in node.names:
            sub = f"{target}.{alias.name}"
            if sub in MODULES:  # from package import module
                module_aliases[alias.asname or alias.name] = sub
            elif _is_private(alias.name) and target != module:
                out.append((module, target, alias.name, node.lineno))
    if module_aliases:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in module_aliases and _is_private(node.attr)
                    and module_aliases[node.value.id] != module):
                out.append((module, module_aliases[node.value.id], node.attr, node.lineno))
    return out


def _all_private_imports() -> list[tuple[str, str, str, int]]:
    return [hit for module, path in sorted(MODULES.items()) for hit in private_imports(module, path)]


# --- the tests ------------------------------------------------------------------------------------

def test_the_source_folders_are_found():
    assert "freebody.reference_impl.conventions" in MODULES
    assert "freebody.adapters.base" in MODULES and "freebody.tolerances" in MODULES


def test_reference_impl_imports_nothing_above_it():
    bad = [v for m, p in MODULES.items() if _layer(m) == "freebody.reference_impl"
           for v in reference_impl_violations(m, p)]
    assert not bad, "\n".join(bad)


def test_adapters_import_only_reference_impl_their_folder_and_the_leaf_modules():
    bad = [v for m, p in MODULES.items() if _layer(m) == "freebody.adapters"
           for v in adapter_violations(m, p)]
    assert not bad, "\n".join(bad)


def test_no_relative_import_climbs_out_of_adapters_or_reference_impl():
    bad = [v for m, p in MODULES.items() if _layer(m) != "freebody"
           for v in climbing_imports(m, p)]
    assert not bad, "\n".join(bad)


def test_no_module_imports_another_modules_private_names():
    bad = [f"{m} imports {name} from {target} (line {line})"
           for m, target, name, line in _all_private_imports()
           if (m, target, name) not in PRIVATE_IMPORT_ALLOWLIST]
    assert not bad, "make these names public (or move them):\n" + "\n".join(bad)


def test_the_allowlist_holds_only_live_offenders():
    live = {(m, target, name) for m, target, name, _ in _all_private_imports()}
    stale = sorted(PRIVATE_IMPORT_ALLOWLIST - live)
    assert not stale, f"fixed: remove from PRIVATE_IMPORT_ALLOWLIST: {stale}"


# --- the rules can fail: planted violations -------------------------------------------------------

@pytest.mark.parametrize("layer, source, rule", [
    ("freebody.adapters", "from .mjx_adapter import _compiled\n", private_imports),
    ("freebody.adapters", "from . import mjx_adapter\nx = mjx_adapter._COMPILED\n", private_imports),
    ("freebody.adapters", "import freebody.run.judge as J\nJ._identity\n", private_imports),
    ("freebody", "from ..run.records import _describe\n", private_imports),
    ("freebody.reference_impl", "from freebody.adapters.base import Adapter\n", reference_impl_violations),
    ("freebody.reference_impl", "import mujoco\n", reference_impl_violations),
    ("freebody.reference_impl", "from freebody.tolerances import SCHEME_ROUNDOFF_FACTOR\n",
     reference_impl_violations),
    ("freebody.adapters", "from freebody.run.judge import identify\n", adapter_violations),
    ("freebody.adapters", "from ..results import document\n", adapter_violations),
    ("freebody.adapters", "from ..tolerances import INPUT_MAGNITUDE_MAX\n", climbing_imports),
])
def test_a_planted_violation_is_caught(tmp_path, layer, source, rule):
    path = tmp_path / "planted.py"
    path.write_text(source, encoding="utf-8")
    module = f"{layer}.sub.planted" if layer == "freebody" else f"{layer}.planted"
    assert rule(module, path), f"{rule.__name__} missed: {source!r}"


@pytest.mark.parametrize("source", [
    "from .loads import LoadSchedule\n",           # a public name of the own folder
    "from freebody.tolerances import MIB\n",      # an allowed leaf module, absolutely
    "from __future__ import annotations\nfrom . import __version__\n",  # dunders are not private
])
def test_allowed_imports_pass(tmp_path, source):
    path = tmp_path / "planted.py"
    path.write_text(source, encoding="utf-8")
    module = "freebody.adapters.planted"
    assert not private_imports(module, path)
    assert not adapter_violations(module, path)
    assert not climbing_imports(module, path)
