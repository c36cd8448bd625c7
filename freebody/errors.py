"""Errors that are the user's input, not a bug: reported as one line, exit code 2, no traceback."""
from __future__ import annotations


class InputError(Exception):
    """Bad input (a case file, a CLI argument, a results or baseline file).

    The message is one line naming the file or option, the key and the reason.
    """

    exit_code = 2


def printable(text) -> str:
    """``text`` safe to print into a terminal: every character that is not printable (control
    characters such as ESC, which starts ANSI escape sequences, BEL, a newline; bidirectional
    overrides, lone surrogates) written as its Python escape (``\\x1b``, ``\\x07``, ``\\n``,
    ``\\u202e``).  For user-provided text (a case name, a path, a key) in messages and displays."""
    s = str(text)
    if s.isprintable():
        return s
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape", "backslashreplace").decode("ascii")
                   for ch in s)


def abbreviated(value, limit: int = 80) -> str:
    """``repr(value)`` for a message: printable, at most about ``limit`` characters (a long list is cut
    with ``...``; a huge integer is described by its number of digits)."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 64:
        digits = len(str(abs(value))) if value.bit_length() < 10_000 else None
        kind = "negative integer" if value < 0 else "integer"
        return f"a {digits}-digit {kind}" if digits is not None else f"an integer of more than 3000 digits"
    try:
        text = repr(value)
    except ValueError:  # e.g. an integer beyond Python's int-to-string limit inside a list
        text = f"<{type(value).__name__}>"
    text = printable(text)
    return text if len(text) <= limit else text[:limit - 3] + "..."
