"""MuJoCo's model format (MJCF) for one free body, and its free-joint state layout: what the
MuJoCo, MJX and Brax adapters share (MJX moves the MuJoCo adapter's compiled model to JAX; Brax
loads the same MJCF into its System).

- :func:`format_floats`: numbers written into the XML as shortest round-trip decimals (exact
  after parsing).
- :func:`inertial_element`: ``<inertial>`` at the body origin with the case's full tensor about
  the COM in the body frame (``fullinertia``), or its principal moments and frame when MuJoCo's
  "A + B >= C" check would fail only by round-off.
- :func:`alignfree_default`: the compiler's ``alignfree`` default (the adapters keep it false, so
  the compiled body frame is the case's body frame).
- :func:`free_joint_trajectory`: free-joint ``qpos`` (7,) = [COM (3,) m world, quaternion (4,)
  (w, x, y, z) body -> world] and ``qvel`` (6,) = [v (3,) m/s world, w (3,) rad/s BODY frame]
  rows as a canonical :class:`~freebody.reference_impl.conventions.Trajectory` (w turned to the
  world frame).
"""
from __future__ import annotations

import mujoco
import numpy as np

from freebody.reference_impl.conventions import Trajectory, angular_velocity_world_from_body
from freebody.reference_impl.rotations import matrix_from_quat, quat_from_matrix

__all__ = ["MUJOCO_PRINCIPAL_AXES_ATOL", "MUJOCO_TRIANGLE_ROUNDOFF", "alignfree_default",
           "format_floats", "free_joint_trajectory", "fullinertia_element", "inertial_element"]

# A flat body (A + B = C exactly, e.g. diag(1, 2, 3)) with off-diagonal terms fails MuJoCo's
# "A + B >= C" check about a third of the time through round-off in the diagonalisation; such a
# violation up to this fraction of C is treated as round-off.
MUJOCO_TRIANGLE_ROUNDOFF = 1e-12
# The principal axes turned into a quaternion and back reproduce the eigenvector matrix to
# round-off (absolute, on entries of magnitude <= 1; np.allclose's default rtol applies as well).
MUJOCO_PRINCIPAL_AXES_ATOL = 1e-12


def format_floats(a) -> str:
    """Floats as shortest round-trip decimal strings for the XML (exact after parsing), separated
    by spaces: a scalar or an array of any shape (flattened)."""
    return " ".join(repr(float(x)) for x in np.ravel(a))


def fullinertia_element(mass: float, I_body: np.ndarray) -> str:
    """``<inertial>`` at the body origin with the full tensor (``fullinertia``), unchecked: what
    :func:`inertial_element` returns whenever MuJoCo accepts it.  mass : kg.  I_body : (3, 3)
    kg m^2, about the COM, body frame."""
    I = np.asarray(I_body, dtype=float)
    return (f'<inertial pos="0 0 0" mass="{format_floats(mass)}" fullinertia="'
            f'{format_floats([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])}"/>')


def inertial_element(mass: float, I_body: np.ndarray) -> str:
    """``<inertial>`` at the body origin with the full tensor (``fullinertia``).

    mass : kg.  I_body : (3, 3) kg m^2, about the COM, body frame.
    When MuJoCo's "A + B >= C" check would fail only by round-off (a flat body given with
    off-diagonal terms), the principal moments and axes are computed here instead (numpy eigh),
    C is set to A + B, and they are passed as ``diaginertia`` + ``quat``: a change of at most
    MUJOCO_TRIANGLE_ROUNDOFF * C.  A real violation is left for MuJoCo to reject.
    """
    I = np.asarray(I_body, dtype=float)
    full = fullinertia_element(mass, I)
    try:
        mujoco.MjModel.from_xml_string(f"<mujoco><worldbody><body><freejoint/>{full}"
                                       f"</body></worldbody></mujoco>")
        return full
    except ValueError as e:
        if "A + B >= C" not in str(e):
            raise
    evals, evecs = np.linalg.eigh(0.5 * (I + I.T))
    if evals[0] + evals[1] < evals[2] * (1.0 - MUJOCO_TRIANGLE_ROUNDOFF):
        return full  # a real violation: MuJoCo's error is the right message
    evals[2] = evals[0] + evals[1]
    if np.linalg.det(evecs) < 0:
        evecs[:, 2] *= -1.0
    quat = quat_from_matrix(evecs)
    _check_rotation(evecs, matrix_from_quat(quat))
    return (f'<inertial pos="0 0 0" mass="{format_floats(mass)}" quat="{format_floats(quat)}" '
            f'diaginertia="{format_floats(evals)}"/>')


def _check_rotation(a: np.ndarray, b: np.ndarray) -> None:
    if not np.allclose(a, b, atol=MUJOCO_PRINCIPAL_AXES_ATOL):
        raise RuntimeError("principal axes of the inertia could not be converted to a quaternion")


def alignfree_default():
    """The compiler's alignfree default (bool), or None when this MuJoCo has no such option."""
    spec = getattr(mujoco, "MjSpec", None)
    if spec is None or not hasattr(spec().compiler, "alignfree"):
        return None
    return bool(spec().compiler.alignfree)


def free_joint_trajectory(Q: np.ndarray, V: np.ndarray, dt: float, k0: int = 0) -> Trajectory:
    """Canonical Trajectory from raw free-joint qpos rows Q (N, 7) and qvel rows V (N, 6) (see the
    module docstring), the first at t = k0 dt (dt in s)."""
    q = Q[:, 3:7].copy()
    return Trajectory.on_grid(k0, dt, Q[:, 0:3], q, V[:, 0:3],
                              angular_velocity_world_from_body(q, V[:, 3:6]))
