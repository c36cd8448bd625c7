"""Input: case files (TOML) and mesh files (OBJ/STL) read and validated into the immutable
:class:`~freebody.reference_impl.problem.Problem` a run starts from.  Bad input raises
:class:`~freebody.errors.InputError` with one line naming the file, the field and the reason."""
from .casefile import bundled_case_paths, load_case, parse_case, resolve_case
from .meshfile import body_from_mesh, read_mesh, read_valid_mesh

__all__ = ["bundled_case_paths", "load_case", "parse_case", "resolve_case", "body_from_mesh",
           "read_mesh", "read_valid_mesh"]
