"""An adapter whose engine is 'installed' (numpy) but broken: its import fails for another reason."""
import numpy  # noqa: F401
from numpy import this_symbol_does_not_exist  # noqa: F401
