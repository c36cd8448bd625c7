"""The ``freebody`` command line: one module per subcommand.

Each subcommand module defines ``add_parser(subparsers)`` and ``run(args) -> int``.  Bad input is an
:class:`~freebody.errors.InputError`: one line on stderr, exit 2, no traceback (``--debug`` shows it).
"""
from __future__ import annotations

import argparse
import importlib
import sys
import warnings

from ..errors import InputError

# subcommand -> module (imported only when chosen, so `freebody list` imports no engine)
COMMANDS = {
    "list": "list_cmd",
    "run": "run_cmd",
}


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
    for name, module in COMMANDS.items():
        importlib.import_module(f"{__name__}.{module}").add_parser(sub)
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
    module = importlib.import_module(f"{__name__}.{COMMANDS[args.command]}")
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
