"""``freebody new-case``: print (or write) a commented case file to start from, valid as is."""
from __future__ import annotations

ORDER = 15

import os
from pathlib import Path

from ..errors import InputError, printable

DEFAULT_NAME = "my-case"


def add_parser(sub) -> None:
    p = sub.add_parser("new-case", help="print a commented case file to start from (every key, or --minimal)",
                       description="Print a case file that runs as is: every key, required or optional, "
                                   "with its default, unit and frame (docs/case-files.md has them in a "
                                   "table).  Then: freebody run FILE.")
    p.add_argument("name", nargs="?", metavar="NAME",
                   help=f"the case's name (default: the --out file's name without .toml, else {DEFAULT_NAME})")
    p.add_argument("--minimal", action="store_true",
                   help="the five-line minimal case instead: a name, dt, duration, the body's mass and "
                        "inertia and its initial angular velocity")
    p.add_argument("--out", metavar="FILE",
                   help="write it to FILE (a new file: an existing one is never overwritten) instead of printing it")
    # the command is dispatched by module name (freebody/cli/new_case_cmd.py), not by its hyphenated name
    p.set_defaults(command=__name__.rsplit(".", 1)[-1][:-len("_cmd")])


def run(args) -> int:
    from ..input.casefile import case_template

    name = args.name if args.name is not None else (Path(args.out).stem if args.out else DEFAULT_NAME)
    text = case_template(name, minimal=args.minimal)
    if args.out is None:
        print(text, end="")
        return 0
    _write_new(Path(args.out), text)
    print(f"wrote {printable(args.out)}; run it with: freebody run {printable(args.out)}")
    return 0


def _write_new(path: Path, text: str) -> None:
    """Create ``path`` with ``text``; InputError if something is already there (a file is never
    overwritten; a folder, FIFO, device, socket or symbolic link there is named as such:
    :func:`freebody.results.io.output_obstacle`); a partly written file is removed (a full disk)."""
    from ..results.io import output_obstacle

    shown = printable(path)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    except FileExistsError:
        kind = output_obstacle(path)
        what = f"{kind} is already there (not a regular file)" if kind else "a file is already there"
        raise InputError(f"--out: {shown}: {what}; new-case never overwrites one "
                         "(give another FILE, or remove it first)") from None
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
    except BaseException:
        os.unlink(path)
        raise
