"""``freebody envs``: the cached environments of engines named with a version (``--engine
mujoco==3.1.6``): list them, create them ahead of a run (CI), clear them, show their folder."""
from __future__ import annotations

ORDER = 95

import sys

ACTIONS = ("list", "create", "clear", "path")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "envs", help="list, create or clear the cached environments of engines named with a version",
        description="An engine named with a version (--engine mujoco==3.1.6) runs in an isolated Python "
                    "environment that freebody creates on first use and caches ($FREEBODY_ENV_DIR, else "
                    "$XDG_CACHE_HOME/freebody/envs, else ~/.cache/freebody/envs).  list: the environments; "
                    "create REQUIREMENT...: build them now (e.g. in CI, before the runs); clear "
                    "[REQUIREMENT...]: remove them (all when none is named); path: print their folder.")
    p.add_argument("action", nargs="?", default="list", choices=ACTIONS, metavar="ACTION",
                   help=f"one of {', '.join(ACTIONS)} (default: list)")
    p.add_argument("requirements", nargs="*", default=[], metavar="REQUIREMENT",
                   help="an engine's package and version, as pip spells it (mujoco==3.1.6)")


def run(args) -> int:
    from ..envs.build import EnvironmentFailed, ensure_environment
    from ..envs.cache import env_root
    from ..envs.requirements import normalise_requirement
    from ..errors import InputError

    if args.action in ("list", "path") and args.requirements:
        raise InputError(f"envs {args.action} takes no REQUIREMENT (got {args.requirements[0]!r})")
    if args.action == "path":
        print(env_root())
        return 0
    if args.action == "list":
        return _list()
    requirements = list(dict.fromkeys(normalise_requirement(r) for r in args.requirements))  # all checked first
    if args.action == "clear":
        return _clear(requirements)
    if not requirements:
        raise InputError("envs create needs at least one REQUIREMENT, e.g. freebody envs create mujoco==3.1.6")
    for requirement in requirements:
        try:
            env = ensure_environment(requirement, progress=_progress)
        except EnvironmentFailed as e:
            if args.debug:
                raise
            _progress(f"error: {e}")
            return 2
        print(f"{env.requirement}  {env.path}")
    return 0


def _progress(line: str) -> None:
    sys.stderr.write(f"freebody: {line}\n")
    sys.stderr.flush()


def _list() -> int:
    """The table of :func:`~freebody.envs.cache.list_environments`."""
    from ..envs.cache import env_root, list_environments
    from ..envs.requirements import canonical_name, requirement_name
    from ..errors import InputError, printable

    envs = list_environments()
    if not envs:
        print(f"no environments in {env_root()}")
        _print_foreign()
        return 0
    rows = [("requirement", "installed", "size MB", "last used", "path")]
    for e in envs:
        requirement = str(e["requirement"])
        try:
            name = requirement_name(requirement)
        except InputError:  # a marker edited by hand
            name = requirement
        version = next((v for d, v in e["installed"].items() if canonical_name(d) == name), "?")
        if e.get("pins") is False:
            version += " (core unpinned)"
        rows.append((printable(requirement), str(version), f"{e['size_bytes'] / 1e6:.0f}",
                     _local_time(e["last_used"]), e["path"]))
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        print("  ".join(f"{c:<{w}}" for c, w in zip(r, widths)) + "  " + r[4])
    _print_foreign()
    return 0


def _print_foreign() -> None:
    """One line for each entry of the environments' folder that freebody did not make (it never
    lists nor removes them)."""
    from ..envs.cache import foreign_entries
    from ..errors import printable

    for path, why in foreign_entries():
        print(f"not freebody's, left alone: {printable(str(path))} ({why})")


def _local_time(stamp) -> str:
    """An ISO time stamp of a marker as local ``YYYY-MM-DD HH:MM`` (``?`` when missing)."""
    from datetime import datetime

    try:
        return datetime.fromisoformat(str(stamp)).astimezone().strftime("%Y-%m-%d %H:%M")
    except ValueError:
        return "?"


def _clear(requirements: list[str]) -> int:
    """Remove the named environments (all when none is named) and say what was removed."""
    from ..envs.cache import clear_environments, env_root

    if not requirements:
        removed = clear_environments()
        for path in removed:
            print(f"removed {path}")
        if not removed:
            print(f"no environments in {env_root()}")
        _print_foreign()
        return 0
    for requirement in requirements:
        removed = clear_environments([requirement])
        for path in removed:
            print(f"removed {path}")
        if not removed:
            print(f"no environment for {requirement} in {env_root()}")
    _print_foreign()
    return 0
