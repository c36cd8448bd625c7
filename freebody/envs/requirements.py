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
    return ParsedRequirement(name, normalised, spec)


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

