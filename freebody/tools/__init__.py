"""Tools beside the run pipeline, each behind a CLI verb: :mod:`.sweep` (many random bodies,
distributions of errors), :mod:`.demo` (the teaching demos), :mod:`.bench` (freebody's own speed
next to the engines') and :mod:`.inertia` (mass properties from geometry).  Import the module you
need; this package re-exports nothing, so importing one tool loads no other."""
