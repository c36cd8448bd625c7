"""freebody's adapter conformance suite on this package's engine, with plain pytest from this
folder (after ``pip install -e .`` into the environment freebody is installed in)::

    python -m pytest

Every check of :class:`freebody.testing.AdapterConformance` runs on each (integrator, precision)
the adapter offers; a check added to freebody's suite runs here too, with no change to this file.
"""
from freebody.testing import AdapterConformance


class TestNumpyEuler(AdapterConformance):
    engine = "numpy-euler"  # the name registered by the entry point in pyproject.toml
