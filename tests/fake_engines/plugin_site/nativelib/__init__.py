"""A stand-in engine package that loads its shared library when imported, as MuJoCo's Python
package loads libmujoco.  The library is ``$FREEBODY_TEST_NATIVELIB`` (a healthy install: the tests
point it at the C library) or, without it, ``libfreebody_nativelib_core.so.4.0.0``, which does not
exist: the install is then broken the way ``pip install mujoco==3.1.6`` over 4.0.0 leaves MuJoCo,
and importing the package raises a real ``OSError`` from the dynamic loader (not an ImportError),
while ``find_spec`` still finds it."""
import ctypes
import os

LIBRARY = os.environ.get("FREEBODY_TEST_NATIVELIB") or "libfreebody_nativelib_core.so.4.0.0"
_LIB = ctypes.CDLL(LIBRARY)  # OSError: cannot open shared object file, when it is missing
