"""Engine requirements as ``--engine`` and ``freebody envs`` take them (``mujoco==3.1.6``): parsed,
checked and normalised, so that one requirement always names one environment
(:func:`freebody.envs.cache.environment_key`).

A requirement is a distribution name, optional extras and optional version specifiers; no URL and
no environment marker.  packaging parses it when it is installed (it is not a dependency), else a
regular expression of the same grammar does.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from ..errors import InputError, printable

# A distribution name (PEP 508), used by the parser and to read names in pip's and uv's messages.
NAME_PATTERN = r"[A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?"
_VERSION_CLAUSE = r"(?:~=|===|==|!=|<=|>=|<|>)[ \t]*[A-Za-z0-9.*+!_-]+"
_REQUIREMENT_RE = re.compile(rf"[ \t]*(?P<name>{NAME_PATTERN})[ \t]*"
                             rf"(?:\[[ \t]*(?P<extras>{NAME_PATTERN}(?:[ \t]*,[ \t]*{NAME_PATTERN})*)?[ \t]*\])?[ \t]*"
                             rf"(?P<spec>{_VERSION_CLAUSE}(?:[ \t]*,[ \t]*{_VERSION_CLAUSE})*)?[ \t]*")


@dataclass(frozen=True)
class ParsedRequirement:
    """A parsed requirement: canonical distribution ``name``, the ``normalised`` text and its version
    ``specifier`` (``""``: any version)."""

    name: str
    normalised: str
    specifier: str


def canonical_name(name: str) -> str:
    """A distribution name as pip compares them (PEP 503): lower case, runs of ``-_.`` as ``-``."""
    return re.sub(r"[-_.]+", "-", name).lower()


def parse_requirement(requirement: str) -> ParsedRequirement:
    """Parse an engine requirement (a name, optional extras and version specifiers; no URL, no
    environment marker).  InputError (one line) when it is not one."""
    text = requirement if isinstance(requirement, str) else ""
    bad = InputError(f"invalid engine requirement {printable(repr(requirement))}: expected a package name "
                     f"with optional version specifiers, e.g. mujoco==3.1.6")
    m = _REQUIREMENT_RE.fullmatch(text)
    if m is None:
        raise bad
    try:
        from packaging.requirements import InvalidRequirement, Requirement
    except ImportError:  # packaging is not a dependency: the regex alone decides
        name = canonical_name(m["name"])
        extras = sorted({canonical_name(e.strip()) for e in (m["extras"] or "").split(",") if e.strip()})
        spec = ",".join(sorted(re.sub(r"\s+", "", c) for c in (m["spec"] or "").split(",") if c.strip()))
    else:
        try:
            req = Requirement(text)
        except InvalidRequirement:
            raise bad from None
        if req.url or req.marker:
            raise bad
        name = canonical_name(req.name)
        extras = sorted(canonical_name(e) for e in req.extras)
        spec = str(req.specifier)
    normalised = name + (f"[{','.join(extras)}]" if extras else "") + spec
    clash = unsatisfiable(spec)
    if clash:
        raise InputError(f"unsatisfiable engine requirement {printable(repr(requirement))}: no version of {name} "
                         f"is {clash}; give one version (mujoco==3.1.6) or a range that holds one")
    return ParsedRequirement(name, normalised, spec)


_CLAUSE_RE = re.compile(r"[ \t]*(~=|===|==|!=|<=|>=|<|>)[ \t]*(\S+?)[ \t]*")


def _version_key():
    """A function from a version's text to a comparable value (None when it cannot compare it):
    packaging's Version when packaging is installed, else the release numbers of a plain
    ``N.N.N`` version, trailing zeros dropped."""
    try:
        from packaging.version import InvalidVersion, Version
    except ImportError:
        def simple(text: str):
            if not re.fullmatch(r"\d+(?:\.\d+)*", text):
                return None
            parts = [int(x) for x in text.split(".")]
            while len(parts) > 1 and parts[-1] == 0:
                parts.pop()
            return tuple(parts)
        return simple

    def full(text: str):
        try:
            return Version(text)
        except InvalidVersion:
            return None
    return full


def _holds(version: str, clauses: list[tuple[str, str]], key) -> bool:
    """Whether ``version`` satisfies every clause (packaging's SpecifierSet when installed; else each
    clause of plain versions compared, a clause it cannot compare counted as holding)."""
    try:
        from packaging.specifiers import SpecifierSet
    except ImportError:
        pass
    else:
        return SpecifierSet(",".join(op + v for op, v in clauses)).contains(version, prereleases=True)
    a = key(version)
    for op, bound in clauses:
        b = key(bound)
        if op == "===":
            ok = version == bound
        elif a is None or b is None:
            continue
        else:
            ok = {"==": a == b, "!=": a != b, "<": a < b, "<=": a <= b, ">": a > b, ">=": a >= b,
                  "~=": a >= b and a[:max(len(b) - 1, 1)] == b[:max(len(b) - 1, 1)]}[op]
        if not ok:
            return False
    return True


def unsatisfiable(spec: str) -> str | None:
    """The clauses of a version specifier (``<3.1.6,==3.1.6``) as words (``==3.1.6 and <3.1.6``) when
    no version can satisfy them all, obviously: an exact version (``==``, ``===``) that another
    clause excludes, or a lower bound above an upper one; else None (pip decides the rest)."""
    clauses = [(m[1], m[2]) for c in spec.split(",") if (m := _CLAUSE_RE.fullmatch(c))]
    key = _version_key()
    words = " and ".join(op + v for op, v in sorted(clauses, key=lambda c: c[0] not in ("==", "===")))
    exact = [v for op, v in clauses if op in ("==", "===") and "*" not in v]
    if exact:
        return None if all(_holds(v, clauses, key) for v in exact) else words
    lows = [(k, op == ">") for op, v in clauses if op in (">", ">=", "~=") and (k := key(v)) is not None]
    highs = [(k, op == "<") for op, v in clauses if op in ("<", "<=") and (k := key(v)) is not None]
    if not lows or not highs:
        return None
    low, low_strict = max(lows)
    high, high_strict = min(highs, key=lambda h: (h[0], not h[1]))
    return words if low > high or (low == high and (low_strict or high_strict)) else None


def normalise_requirement(requirement: str) -> str:
    """The normalised text of an engine requirement (``MuJoCo == 3.1.6`` -> ``mujoco==3.1.6``);
    InputError when it is not a valid requirement."""
    return parse_requirement(requirement).normalised


def requirement_name(requirement: str) -> str:
    """The canonical distribution name of an engine requirement (``MuJoCo==3.1.6`` -> ``mujoco``);
    InputError when it is not a valid requirement."""
    return parse_requirement(requirement).name


def declared_name(text: str) -> str:
    """The canonical distribution name at the start of a declared requirement (``numpy>=1.24`` ->
    ``numpy``; freebody's metadata, already valid), leniently: the text itself when none is."""
    m = re.match(NAME_PATTERN, text.strip())
    return canonical_name(m.group(0)) if m else text.strip()

