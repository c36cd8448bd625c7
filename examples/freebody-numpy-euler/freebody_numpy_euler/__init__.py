"""freebody-numpy-euler: a tiny numpy free-body engine (:mod:`.engine`) and its freebody adapter
(:mod:`.adapter`), registered as the engine ``numpy-euler``.  Importing this package does not
import freebody: the harness imports :mod:`.adapter` only when a run needs it."""

__version__ = "0.1.0"
