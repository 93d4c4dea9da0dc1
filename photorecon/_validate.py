"""Run-time checks of shapes, finiteness and rigid transforms, raising ``BadArgumentError`` (a ``ValueError``).

Never ``assert`` on user data: asserts vanish under ``python -O``.
"""
from __future__ import annotations

import numpy as np

from .errors import BadArgumentError

ORTHO_TOL = 1e-6


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
    """3x3 float64 rotation: orthonormal to ``ORTHO_TOL`` with determinant +1."""
    R = as_array(R, (3, 3), name)
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > ORTHO_TOL:
        raise BadArgumentError(f"{name}: expected an orthonormal rotation (R^T R = I), deviation is {err:.3g}")
    det = np.linalg.det(R)
    if det < 0:
        raise BadArgumentError(f"{name}: expected a proper rotation (det +1), got det {det:.6f} (a reflection: check the axis convention)")
    return R


def as_rigid(T, name: str = "transform") -> np.ndarray:
    """4x4 float64 rigid transform [R t; 0 0 0 1] with a proper rotation R."""
    T = as_array(T, (4, 4), name)
    if np.abs(T[3] - np.array([0.0, 0.0, 0.0, 1.0])).max() > 1e-9:
        raise BadArgumentError(f"{name}: expected last row [0 0 0 1], got {T[3].tolist()}")
    as_rotation(T[:3, :3], f"{name} rotation block")
    return T


def _fmt(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"
