"""The ``freebody`` command line: one module per subcommand.

Each subcommand is a module ``freebody/cli/<name>_cmd.py`` that defines ``ORDER`` (its place in
``--help``), ``add_parser(subparsers)`` and ``run(args) -> int``, and imports nothing heavy (no
engine, no matplotlib) at module level.  Bad input is an :class:`~freebody.errors.InputError`:
one line on stderr, exit 2, no traceback (``--debug`` shows it).
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings

from ..errors import InputError


def _commands() -> dict[str, object]:
    """Subcommand modules (``*_cmd``) of this package, in their ORDER."""
    mods = [importlib.import_module(f"{__name__}.{m.name}") for m in pkgutil.iter_modules(__path__)
            if m.name.endswith("_cmd")]
    return {m.__name__.rsplit(".", 1)[-1][:-4]: m for m in sorted(mods, key=lambda m: m.ORDER)}


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors: one line, exit 2
        self.exit(2, f"freebody: error: {message} (see freebody {self.prog.split()[-1]} --help)\n"
                  if " " in self.prog else f"freebody: error: {message} (see freebody --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = _Parser(prog="freebody", description="Cross-validate rigid-body physics engines on the free rigid body.")
    parser.add_argument("--version", action="version", version=f"freebody {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks for errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for module in _commands().values():
        module.add_parser(sub)
    return parser


def _warning_line(message, category, filename, lineno, file=None, line=None):
    sys.stderr.write(f"freebody: warning: {message}\n")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    warnings.showwarning = _warning_line
    module = _commands()[args.command]
    try:
        return int(module.run(args) or 0)
    except InputError as e:
        if args.debug:
            raise
        sys.stderr.write(f"freebody: error: {e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("freebody: interrupted\n")
        return 130
    except BrokenPipeError:
        return 0
