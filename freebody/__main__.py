"""``python -m freebody``: the ``freebody`` command (:func:`freebody.cli.main`, which handles
Ctrl-C from its first import on)."""
import os
import sys

from .cli import main

code = main()
if code > 128:  # interrupted by a signal (128 + its number)
    # Python's -m would end the process by SIGINT instead of this code when the KeyboardInterrupt
    # was raised inside an exec() of a string (a dataclass's methods being made, say: CPython's
    # unhandled_keyboard_interrupt flag, which a caught exception does not clear)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    os._exit(code)
sys.exit(code)
