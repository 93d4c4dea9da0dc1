"""Run-time checks of shapes, finiteness and rigid transforms, raising ``BadArgumentError`` (a ``ValueError``).

Never ``assert`` on user data: asserts vanish under ``python -O``.
"""
from __future__ import annotations

import numpy as np

from .errors import BadArgumentError

ORTHO_TOL = 1e-6  # a rotation block this close to orthonormal is used as given
# float32-rounded or few-digit camera files (NeRF-synthetic's transforms_*.json: ~1e-6 .. 1e-5) deviate by more;
# up to this deviation the block is snapped to the nearest rotation, beyond it it is a scale or a shear
SNAP_TOL = 1e-3


def as_array(x, shape: tuple, name: str, dtype=np.float64) -> np.ndarray:
    """Return ``x`` as an array of ``dtype`` whose shape matches ``shape`` (``-1`` = any length), all finite."""
    try:
        a = np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise BadArgumentError(f"{name}: expected a numeric array of shape {_fmt(shape)}, got {type(x).__name__} ({exc})") from None
    if a.ndim != len(shape) or any(s not in (-1, n) for s, n in zip(shape, a.shape)):
        raise BadArgumentError(f"{name}: expected shape {_fmt(shape)}, got {a.shape}")
    if np.issubdtype(a.dtype, np.floating) and not np.all(np.isfinite(a)):
        bad = int(np.size(a) - np.count_nonzero(np.isfinite(a)))
        raise BadArgumentError(f"{name}: expected finite values, found {bad} NaN/inf entries")
    return a


def as_points(x, name: str = "points") -> np.ndarray:
    """(N, 3) float64, finite."""
    return as_array(x, (-1, 3), name)


def as_rotation(R, name: str = "rotation") -> np.ndarray:
    """3x3 float64 rotation with determinant +1. Orthonormal to ``ORTHO_TOL``: returned as given; to
    ``SNAP_TOL`` (rounding, as in float32 camera files): the nearest rotation (SVD, Frobenius norm); beyond
    that (a scale or a shear) or with det < 0 (a reflection): ``BadArgumentError``."""
    R = as_array(R, (3, 3), name)
    det = np.linalg.det(R)
    if det < 0:
        raise BadArgumentError(f"{name}: expected a proper rotation (det +1), got det {det:.6f} (a reflection: check the axis convention)")
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err <= ORTHO_TOL:
        return R
    if err > SNAP_TOL:
        sv = np.linalg.svd(R, compute_uv=False)
        raise BadArgumentError(f"{name}: expected an orthonormal rotation (R^T R = I), deviation is {err:.3g} "
                               f"(singular values {sv[0]:.6g}, {sv[1]:.6g}, {sv[2]:.6g}: a scale or shear, more than "
                               f"the {SNAP_TOL:g} that rounding explains)")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt  # det +1: R is within SNAP_TOL of orthonormal with det > 0


def as_rigid(T, name: str = "transform") -> np.ndarray:
    """4x4 float64 rigid transform [R t; 0 0 0 1] with a proper rotation R (a rotation block within
    ``SNAP_TOL`` of orthonormal is returned snapped to the nearest rotation, see ``as_rotation``)."""
    T = as_array(T, (4, 4), name)
    if np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise BadArgumentError(f"{name}: expected last row [0 0 0 1], got {T[3].tolist()}")
    R = as_rotation(T[:3, :3], f"{name} rotation block")
    if not np.shares_memory(R, T):  # snapped
        T = T.copy()
        T[:3, :3] = R
    return T


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
