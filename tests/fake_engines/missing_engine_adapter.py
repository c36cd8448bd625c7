"""An adapter whose engine package is not installed: importing it raises ImportError(name=...)."""
import freebody_test_engine_that_is_not_installed  # noqa: F401
