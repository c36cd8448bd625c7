"""Rotation helpers in freebody's convention: Hamilton quaternions (w, x, y, z), body -> world.

All functions accept leading batch axes: "(..., 4)" means any number of leading axes.
"""
from __future__ import annotations

import numpy as np

# Below this rotation angle (rad) Exp takes sin(a/2)/a from its series 1/2 - a^2/48 + a^4/3840:
# the first term left out, a^6/645120, is under 2e-30 there (far below round-off), and at a = 0
# sin(a/2)/a cannot be evaluated.  compiled.quat_from_rotvec uses the same cut-off.
EXP_SERIES_ANGLE_RAD = 1e-4

__all__ = [
    "skew", "quat_multiply", "quat_conjugate", "quat_normalize", "matrix_from_quat",
    "quat_from_matrix", "quat_from_rotvec", "rotvec_from_quat", "geodesic_angle",
    "nearest_rotation", "gram_schmidt", "orthonormality_error", "quat_canonical",
]


def skew(w: np.ndarray) -> np.ndarray:
    """[w], the (..., 3, 3) cross-product matrix: [w] @ v = w x v.  w: (..., 3)."""
    w = np.asarray(w, dtype=float)
    S = np.zeros(w.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -w[..., 2], w[..., 1]
    S[..., 1, 0], S[..., 1, 2] = w[..., 2], -w[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -w[..., 1], w[..., 0]
    return S


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (..., 4) quaternions (w, x, y, z): rotate by b, then by a."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """(w, -x, -y, -z): the inverse of a unit quaternion.  q: (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """q / |q| along the last axis.  q: (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """The representative of +-q with w >= 0 (for printing and stable comparisons)."""
    q = np.asarray(q, dtype=float)
    return np.where(q[..., :1] < 0, -q, q)


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """R(q), shape (..., 3, 3), body -> world, for a (..., 4) quaternion (normalised here)."""
    q = quat_normalize(q)
    if q.shape == (4,):  # one quaternion: the same float operations on scalars, 5x faster
        w, x, y, z = q.tolist()
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a (..., 3, 3) rotation matrix (Shepperd's method:
    the largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 picks a well-conditioned formula).  Non-finite -> NaN."""
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    d21, d02, d10 = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    s01, s02, s12 = R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1]
    cands = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.argmax(np.nan_to_num(cands, nan=-np.inf), axis=-1)
        r = np.sqrt(np.maximum(np.take_along_axis(cands, k[..., None], -1)[..., 0], 0.0))
        h = 0.5 / r
        options = np.stack([
            np.stack([0.5 * r, d21 * h, d02 * h, d10 * h], -1),
            np.stack([d21 * h, 0.5 * r, s01 * h, s02 * h], -1),
            np.stack([d02 * h, s01 * h, 0.5 * r, s12 * h], -1),
            np.stack([d10 * h, s02 * h, s12 * h, 0.5 * r], -1),
        ], -2)
        q = np.take_along_axis(options, k[..., None, None], -2)[..., 0, :]
        q = quat_canonical(quat_normalize(q))
    bad = ~np.all(np.isfinite(R), axis=(-2, -1))
    return np.where(bad[..., None], np.nan, q)


def quat_from_rotvec(phi: np.ndarray) -> np.ndarray:
    """Exp: the unit quaternion of a rotation vector phi (axis * angle, rad), shape (..., 3) -> (..., 4).

    Uses a Taylor series for small angles, so it is accurate down to phi = 0.
    """
    phi = np.asarray(phi, dtype=float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < EXP_SERIES_ANGLE_RAD
    # sin(a/2)/a; series 1/2 - a^2/48 + a^4/3840 for small a
    safe = np.where(small, 1.0, angle)
    k = np.where(small, 0.5 - angle**2 / 48.0 + angle**4 / 3840.0, np.sin(half) / safe)
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def rotvec_from_quat(q: np.ndarray) -> np.ndarray:
    """Log: the rotation vector (..., 3) of a (..., 4) quaternion, angle in [0, pi]."""
    q = quat_canonical(quat_normalize(q))
    vn = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(vn, q[..., :1])
    small = vn < 1e-12
    k = np.where(small, 2.0, angle / np.where(small, 1.0, vn))
    return k * q[..., 1:]


def geodesic_angle(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of the rotation between q_a and q_b, invariant to q -> -q.

    2 atan2(|vec(d)|, |w(d)|) with d = q_a^-1 q_b: accurate down to 1e-16, unlike arccos.
    q_a, q_b : (..., 4), normalised here.  Returns shape (...).
    """
    d = quat_multiply(quat_conjugate(quat_normalize(q_a)), quat_normalize(q_b))
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation closest to M in the Frobenius norm (polar decomposition by SVD).  M: (..., 3, 3).

    Non-finite matrices give NaN (a blown-up integration stays a value, not an exception).
    """
    M = np.asarray(M, dtype=float)
    ok = np.all(np.isfinite(M), axis=(-2, -1))
    out = np.full(M.shape, np.nan)
    U, _, Vt = np.linalg.svd(M[ok])
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones(U.shape[:-1])
    D[..., 2] = d
    out[ok] = (U * D[..., None, :]) @ Vt
    return out


def gram_schmidt(M: np.ndarray) -> np.ndarray:
    """Re-orthonormalise the columns of M (..., 3, 3) by classical Gram-Schmidt, in column order."""
    M = np.asarray(M, dtype=float)
    c0 = M[..., :, 0]
    c0 = c0 / np.linalg.norm(c0, axis=-1, keepdims=True)
    c1 = M[..., :, 1] - np.sum(c0 * M[..., :, 1], axis=-1, keepdims=True) * c0
    c1 = c1 / np.linalg.norm(c1, axis=-1, keepdims=True)
    c2 = (M[..., :, 2] - np.sum(c0 * M[..., :, 2], axis=-1, keepdims=True) * c0
          - np.sum(c1 * M[..., :, 2], axis=-1, keepdims=True) * c1)
    c2 = c2 / np.linalg.norm(c2, axis=-1, keepdims=True)
    return np.stack([c0, c1, c2], axis=-1)


def orthonormality_error(R: np.ndarray) -> np.ndarray:
    """||R^T R - 1||_F of a (..., 3, 3) matrix; zero for a rotation.  Returns shape (...)."""
    R = np.asarray(R, dtype=float)
    E = np.swapaxes(R, -1, -2) @ R - np.eye(3)
    return np.sqrt(np.sum(E * E, axis=(-2, -1)))
