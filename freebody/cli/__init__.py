"""The ``freebody`` command line: one module per subcommand.

Each subcommand is a module ``freebody/cli/<name>_cmd.py`` that defines ``ORDER`` (its place in
``--help``), ``add_parser(subparsers)`` and ``run(args) -> int``, and imports nothing heavy (no
engine, no matplotlib) at module level.  Bad input is an :class:`~freebody.errors.InputError`:
one line on stderr, exit 2, no traceback (``--debug`` shows it).  So is an error of the environment
(an OSError: a full disk, a file or folder that cannot be written) and a standard output that cannot
be written (a closed pipe, a full device): the output is incomplete, so the exit code is never 0.
User-provided text in these lines is escaped (:func:`~freebody.errors.printable`).
"""
from __future__ import annotations

import os
import signal
import sys


def _exit_interrupted(signum, frame) -> None:
    """SIGINT where :func:`main` cannot catch it (while this module imports, at exit): one line,
    exit 130 (128 + SIGINT), no traceback."""
    try:
        sys.stderr.write("freebody: interrupted\n")
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass
    if _importing:  # unwind quietly (SystemExit prints nothing), whoever imports this module
        raise SystemExit(128 + signum)
    os._exit(128 + signum)  # Python is exiting: nothing left to unwind


def _on_sigint(handler):
    """Set the SIGINT handler; the previous one (None outside the main thread, where Python
    delivers no signal)."""
    try:
        return signal.signal(signal.SIGINT, handler)
    except ValueError:
        return None


# first of all: a Ctrl-C while the imports below run is an exit 130 with one line, not a traceback
_importing = True
_SIGINT_BEFORE = _on_sigint(_exit_interrupted)

import argparse  # noqa: E402 (after the handler, on purpose)
import errno  # noqa: E402
import importlib  # noqa: E402
import pkgutil  # noqa: E402
import warnings  # noqa: E402

from ..errors import InputError, printable  # noqa: E402


_COMMANDS: dict[str, object] = {}  # this process's subcommand modules, found once (:func:`_commands`)


def _commands() -> dict[str, object]:
    """Subcommand modules (``*_cmd``) of this package, in their ORDER.  Each is cheap to import:
    what a command runs is imported by its ``run`` (tests/test_fixed_costs.py checks it)."""
    if not _COMMANDS:
        mods = [importlib.import_module(f"{__name__}.{m.name}") for m in pkgutil.iter_modules(__path__)
                if m.name.endswith("_cmd")]
        _COMMANDS.update((m.__name__.rsplit(".", 1)[-1][:-4], m) for m in sorted(mods, key=lambda m: m.ORDER))
    return dict(_COMMANDS)


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own errors: one line, exit 2
        message = printable(message)
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
    _stderr_line(f"freebody: warning: {printable(message)}")


def _stderr_line(text: str) -> None:
    """Write one line to stderr; nothing if stderr itself cannot be written."""
    try:
        sys.stderr.write(text + "\n")
        sys.stderr.flush()
    except (OSError, ValueError, AttributeError):
        pass


class _StdoutError(OSError):
    """Standard output could not be written (a pipe whose reader is gone, a full device)."""


class _Stdout:
    """``sys.stdout`` while a command runs: a write or flush that fails raises :class:`_StdoutError`,
    so that the error is known to be stdout's (and not a file's)."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as e:
            raise _StdoutError(e.errno, e.strerror) from None

    def flush(self):
        try:
            return self._stream.flush()
        except OSError as e:
            raise _StdoutError(e.errno, e.strerror) from None

    def __getattr__(self, name):
        return getattr(self._stream, name)


def _silence_stdout(stream) -> None:
    """Send what is left of stdout to the null device, so that Python's flush at exit does not
    fail a second time (the recipe of the Python documentation for a broken pipe)."""
    try:
        target = stream.fileno()
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, target)
        os.close(fd)
    except (OSError, ValueError, AttributeError):
        pass


def _os_error_line(e: OSError) -> str:
    """One line for an error of the environment: what could not be done, where, and why."""
    what = printable(e.filename) if e.filename is not None else None
    why = e.strerror or str(e)
    hint = {errno.ENOSPC: " (the disk is full)", errno.EFBIG: " (the file size limit is reached)",
            errno.EDQUOT: " (the disk quota is reached)"}.get(e.errno, "")
    return f"freebody: error: {what}: {why}{hint}" if what else f"freebody: error: {why}{hint}"


def _closed(fd: int) -> bool:
    """Whether the file descriptor ``fd`` is closed (``freebody ... >&-``)."""
    try:
        os.fstat(fd)
        return False
    except OSError:
        return True


def main(argv: list[str] | None = None) -> int:
    """The ``freebody`` command (``argv``: the arguments; None: ``sys.argv[1:]``, a real command
    line).  Ctrl-C, SIGTERM or SIGHUP at any instant (the imports of the command's modules
    included) exits 128 + the signal's number with one line; with ``argv`` None, a Ctrl-C while
    Python exits too (:func:`_exit_interrupted`)."""
    try:
        return _main(argv)
    except KeyboardInterrupt as e:  # Ctrl-C; SIGTERM, SIGHUP during a run (run/interrupts.py)
        signum = int(getattr(e, "signum", signal.SIGINT))  # run.interrupts.Interrupted's
        what = "interrupted" if signum == signal.SIGINT else f"terminated by {signal.Signals(signum).name}"
        _stderr_line(f"freebody: {what}")
        return 128 + signum
    finally:
        if argv is None:  # a real command: what is left is Python's exit (atexit, the workers' joins)
            _on_sigint(_exit_interrupted)


def _main(argv: list[str] | None) -> int:
    if _closed(1):  # a file freebody opens would become its stdout, and the workers' too
        _stderr_line("freebody: error: standard output is closed; freebody prints its results there "
                     "(redirect it to a file instead)")
        return 2
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    warnings.showwarning = _warning_line
    module = _commands()[args.command]
    stdout = sys.stdout
    sys.stdout = _Stdout(stdout)
    try:
        code = int(module.run(args) or 0)
        sys.stdout.flush()  # a write error of buffered output (a full device) here, not at exit
        return code
    except InputError as e:
        if args.debug:
            raise
        _stderr_line(f"freebody: error: {printable(e)}")
        return 2
    except _StdoutError as e:  # a closed pipe (freebody ... | head -1), a full device
        if args.debug:
            raise
        _silence_stdout(stdout)
        why = ("the reading end of the pipe was closed" if e.errno == errno.EPIPE
               else printable(e.strerror or e))
        _stderr_line(f"freebody: error: standard output: cannot write: {why}; the output is incomplete")
        return 2
    except OSError as e:  # a full disk, a file or folder that cannot be written
        if args.debug:
            raise
        _stderr_line(_os_error_line(e))
        return 2
    finally:
        sys.stdout = stdout


# imported: Ctrl-C raises KeyboardInterrupt again (main catches it)
_on_sigint(_SIGINT_BEFORE if _SIGINT_BEFORE is not None else signal.default_int_handler)
_importing = False
