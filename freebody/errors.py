"""Errors that are the user's input, not a bug: reported as one line, exit code 2, no traceback."""
from __future__ import annotations


class InputError(Exception):
    """Bad input (a case file, a CLI argument, a results or baseline file).

    The message is one line naming the file or option, the key and the reason.
    """

    exit_code = 2
