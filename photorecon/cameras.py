"""Camera model: intrinsics with COLMAP's distortion models, poses, projection and back-projection.

Conventions used everywhere inside photorecon (converted only at the edges, see ``conventions``):

* A pose is ``cam_from_world``: a 4x4 float64 rigid transform taking world points to camera points,
  ``X_cam = R @ X_world + t``, in **OpenCV camera axes** (x right, y down, z forward).
* Pixel coordinates ``(u, v)`` are (column, row) with **(0, 0) at the centre of the top-left pixel**
  (OpenCV). COLMAP puts that centre at (0.5, 0.5); ``conventions.intrinsics_from_colmap`` / ``colmap_from_intrinsics`` convert.
* Depth maps are **z-depth** (distance along the optical axis, not along the ray) in scene units,
  shape (H, W), 0 where there is no surface.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ._validate import as_array, as_points, as_rigid
from .errors import BadArgumentError

# COLMAP camera models: name -> parameter names in COLMAP's order.
COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}
_DIST_KEYS = ("k1", "k2", "p1", "p2", "k3", "k4")
_MODEL_KEYS = {"SIMPLE_PINHOLE": (), "PINHOLE": (), "SIMPLE_RADIAL": ("k1",), "RADIAL": ("k1", "k2"),
               "OPENCV": ("k1", "k2", "p1", "p2"), "OPENCV_FISHEYE": ("k1", "k2", "k3", "k4")}


@dataclass(frozen=True)
class Intrinsics:
    """A camera's intrinsics.

    ``fx, fy, cx, cy`` in pixels with pixel (0, 0) at the centre of the top-left pixel (OpenCV);
    ``width, height`` in pixels; ``model`` one of ``COLMAP_MODELS``; ``k1, k2`` radial and ``p1, p2``
    tangential distortion with COLMAP's (= OpenCV's) formulas, applied to normalised coordinates.
    ``OPENCV_FISHEYE`` (COLMAP's, = OpenCV's ``cv2.fisheye`` model): the equidistant projection, a point at
    angle theta from the axis lands at radius ``theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``
    in normalised coordinates; it always counts as distorted (all k = 0 is still no pinhole).
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "PINHOLE"
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0

    def __post_init__(self):
        if self.model not in COLMAP_MODELS:
            raise BadArgumentError(f"camera model: expected one of {sorted(COLMAP_MODELS)}, got {self.model!r}")
        if not (int(self.width) == self.width and int(self.height) == self.height and self.width > 0 and self.height > 0):
            raise BadArgumentError(f"image size: expected positive integer width and height, got {self.width}x{self.height}")
        vals = [self.fx, self.fy, self.cx, self.cy] + [getattr(self, k) for k in _DIST_KEYS]
        if not all(math.isfinite(float(v)) for v in vals):
            raise BadArgumentError(f"intrinsics: expected finite values, got fx={self.fx} fy={self.fy} cx={self.cx} cy={self.cy}")
        if self.fx <= 0 or self.fy <= 0:
            raise BadArgumentError(f"focal length: expected fx, fy > 0 pixels, got fx={self.fx}, fy={self.fy}")
        if self.model.startswith("SIMPLE") or self.model == "RADIAL":
            if abs(self.fx - self.fy) > 1e-9 * self.fx:
                raise BadArgumentError(f"{self.model} has one focal length, got fx={self.fx} != fy={self.fy}")
        allowed = _MODEL_KEYS[self.model]
        for k in _DIST_KEYS:
            if k not in allowed and getattr(self, k) != 0.0:
                raise BadArgumentError(f"{self.model} has no parameter {k}, got {k}={getattr(self, k)}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # --- construction -------------------------------------------------------------------------------
    @classmethod
    def from_K(cls, K, width: int, height: int) -> "Intrinsics":
        """From a 3x3 calibration matrix (OpenCV pixel convention). Skew must be zero."""
        K = as_array(K, (3, 3), "K")
        if abs(K[0, 1]) > 1e-9 or np.abs(K[2] - [0, 0, 1]).max() > 1e-9 or K[1, 0] != 0:
            raise BadArgumentError(f"K: expected [[fx,0,cx],[0,fy,cy],[0,0,1]], got {K.tolist()}")
        return cls(width, height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))

    @classmethod
    def from_fov(cls, width: int, height: int, fov_deg: float, axis: str = "x") -> "Intrinsics":
        """Square pixels, principal point at the image centre, ``fov_deg`` across the full ``axis`` ('x' or 'y')."""
        if not 0 < fov_deg < 180:
            raise BadArgumentError(f"field of view: expected 0 < fov < 180 degrees, got {fov_deg}")
        if axis not in ("x", "y"):
            raise BadArgumentError(f"fov axis: expected 'x' or 'y', got {axis!r}")
        size = width if axis == "x" else height
        f = 0.5 * size / math.tan(math.radians(fov_deg) / 2)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    # --- properties ---------------------------------------------------------------------------------
    @property
    def K(self) -> np.ndarray:
        """3x3 calibration matrix, OpenCV pixel convention."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height)."""
        return self.width, self.height

    @property
    def has_distortion(self) -> bool:
        return self.fisheye or any(getattr(self, k) != 0.0 for k in _DIST_KEYS)

    @property
    def fisheye(self) -> bool:
        return self.model == "OPENCV_FISHEYE"

    @property
    def dist_coeffs(self) -> np.ndarray:
        """OpenCV's distortion vector: (k1, k2, p1, p2) for ``cv2.undistort``, or (k1, k2, k3, k4) for
        ``cv2.fisheye`` when ``fisheye``."""
        return np.array([getattr(self, k) for k in (("k1", "k2", "k3", "k4") if self.fisheye else _DIST_KEYS[:4])])

    def pinhole(self) -> "Intrinsics":
        """The same camera with distortion dropped (what undistorted images use)."""
        return replace(self, model="PINHOLE", k1=0.0, k2=0.0, p1=0.0, p2=0.0, k3=0.0, k4=0.0)

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics for the image resized to ``width`` x ``height``.

        Pixel centres map as ``u' = (u + 0.5) * sx - 0.5``, so ``cx`` is not simply multiplied.
        """
        if width <= 0 or height <= 0:
            raise BadArgumentError(f"resize: expected a positive size, got {width}x{height}")
        sx, sy = width / self.width, height / self.height
        return replace(self, width=int(width), height=int(height), fx=self.fx * sx, fy=self.fy * sy,
                       cx=(self.cx + 0.5) * sx - 0.5, cy=(self.cy + 0.5) * sy - 0.5)

    # --- distortion ---------------------------------------------------------------------------------
    def distort(self, xy: np.ndarray) -> np.ndarray:
        """Normalised undistorted (N, 2) -> normalised distorted (N, 2), COLMAP/OpenCV formulas."""
        if not self.has_distortion:
            return xy
        if self.fisheye:
            r = np.hypot(xy[:, 0], xy[:, 1])
            th = np.arctan(r)
            t2 = th * th
            th_d = th * (1 + t2 * (self.k1 + t2 * (self.k2 + t2 * (self.k3 + t2 * self.k4))))
            with np.errstate(divide="ignore", invalid="ignore"):
                s = np.where(r > 1e-12, th_d / np.where(r > 1e-12, r, 1.0), 1.0)
            return xy * s[:, None]
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        dx = 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        dy = self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return np.stack([x * radial + dx, y * radial + dy], axis=1)

    def undistort(self, xy_d: np.ndarray, iterations: int = 100) -> np.ndarray:
        """Normalised distorted (N, 2) -> undistorted (N, 2) by Newton iterations (numerical Jacobian)."""
        if not self.has_distortion:
            return xy_d
        xy = xy_d.copy()
        eps = 1e-7
        for _ in range(iterations):
            f = self.distort(xy) - xy_d
            fx = (self.distort(xy + [eps, 0.0]) - self.distort(xy - [eps, 0.0])) / (2 * eps)
            fy = (self.distort(xy + [0.0, eps]) - self.distort(xy - [0.0, eps])) / (2 * eps)
            a, b, c, d = fx[:, 0], fy[:, 0], fx[:, 1], fy[:, 1]
            det = a * d - b * c
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            step = np.stack([(d * f[:, 0] - b * f[:, 1]) / det, (-c * f[:, 0] + a * f[:, 1]) / det], axis=1)
            xy = xy - step
            if np.abs(step).max(initial=0.0) < 1e-14:
                break
        return xy

    # --- pixels <-> rays ----------------------------------------------------------------------------
    def project_cam(self, points_cam) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (N, 3) -> pixels (N, 2) and z-depth (N,). Points with z <= 0 get NaN pixels."""
        P = as_points(points_cam, "points_cam")
        z = P[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = P[:, :2] / z[:, None]
        xy[z <= 0] = np.nan
        xy = self.distort(xy)
        uv = np.stack([self.fx * xy[:, 0] + self.cx, self.fy * xy[:, 1] + self.cy], axis=1)
        return uv, z

    def pixel_rays(self, uv) -> np.ndarray:
        """Pixels (N, 2) -> camera-frame ray directions (N, 3) with **z = 1** (so depth * ray = point)."""
        uv = as_array(uv, (-1, 2), "pixels")
        xy = np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy], axis=1)
        xy = self.undistort(xy)
        return np.concatenate([xy, np.ones((len(xy), 1))], axis=1)

    def pixel_grid(self, step: int = 1) -> np.ndarray:
        """All pixel centres as (H, W, 2) array of (u, v) = (column, row); with ``step``, every step-th row and
        column from the first (the grid of ``depth[::step, ::step]``). The one place the grid is built."""
        u, v = np.meshgrid(np.arange(0, self.width, step, dtype=np.float64),
                           np.arange(0, self.height, step, dtype=np.float64), indexing="xy")
        return np.stack([u, v], axis=-1)


# --- poses ----------------------------------------------------------------------------------------------
def invert_rigid(T) -> np.ndarray:
    """Inverse of a 4x4 rigid transform, exactly (R^T, -R^T t)."""
    T = as_rigid(T)
    out = np.eye(4)
    out[:3, :3] = T[:3, :3].T
    out[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return out


def rigid(R, t) -> np.ndarray:
    """4x4 from rotation (3, 3) and translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = as_array(R, (3, 3), "R")
    T[:3, 3] = as_array(t, (3,), "t")
    return as_rigid(T)


def camera_center(cam_from_world) -> np.ndarray:
    """World position of the camera centre, -R^T t."""
    T = as_rigid(cam_from_world, "cam_from_world")
    return -T[:3, :3].T @ T[:3, 3]


def transform_points(a_from_b, points_b) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    P = as_points(points_b)
    T = as_array(a_from_b, (4, 4), "transform")
    return P @ T[:3, :3].T + T[:3, 3]


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``cam_from_world`` (OpenCV axes) of a camera at ``eye`` looking at ``target``; image 'up' (-y) towards ``up``.

    Raises if ``up`` is parallel to the viewing direction.
    """
    eye = as_array(eye, (3,), "eye")
    target = as_array(target, (3,), "target")
    up = as_array(up, (3,), "up")
    z = target - eye
    n = np.linalg.norm(z)
    if n < 1e-12:
        raise BadArgumentError("look_at: eye and target coincide; expected distinct points")
    z /= n
    x = np.cross(z, up)  # camera x (right) = forward x up  (OpenCV: y down)
    nx = np.linalg.norm(x)
    if nx < 1e-9 * max(1.0, np.linalg.norm(up)):
        raise BadArgumentError(f"look_at: up {up.tolist()} is parallel to the viewing direction; pick another up vector")
    x /= nx
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    return rigid(R, -R @ eye)


# --- camera placements ---------------------------------------------------------------------------------
def ring_positions(n: int, radius: float = 3.0, elevation_deg: float = 0.0, center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``n`` positions on a horizontal ring (around +z) at ``elevation_deg`` above the xy plane."""
    _check_count(n, radius)
    az = np.linspace(0, 2 * np.pi, n, endpoint=False)
    el = np.radians(elevation_deg)
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(n, np.sin(el))], axis=1)
    return np.asarray(center, float) + radius * d


def sphere_positions(n: int, radius: float = 3.0, center=(0.0, 0.0, 0.0), hemisphere: bool = False,
                     min_elevation_deg: float = 5.0) -> np.ndarray:
    """``n`` near-uniform positions on a Fibonacci sphere (or its upper half, z above ``min_elevation_deg``)."""
    _check_count(n, radius)
    i = np.arange(n) + 0.5
    if hemisphere:
        zmin = np.sin(np.radians(min_elevation_deg))
        z = 1 - i / n * (1 - zmin)
    else:
        z = 1 - 2 * i / n
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    phi = np.pi * (3 - np.sqrt(5)) * np.arange(n)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return np.asarray(center, float) + radius * d


def look_at_views(positions, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> list[np.ndarray]:
    """``cam_from_world`` for each position looking at ``target``; where ``up`` is parallel to the view
    direction (a camera straight above), the world y axis is used as up instead."""
    out = []
    for p in np.asarray(positions, float):
        d = np.asarray(target, float) - p
        u = np.asarray(up, float)
        if np.linalg.norm(np.cross(d, u)) < 1e-6 * np.linalg.norm(d) * np.linalg.norm(u):
            u = np.array([0.0, 1.0, 0.0])
        out.append(look_at(p, target, u))
    return out


def _check_count(n, radius):
    if int(n) != n or n < 1:
        raise BadArgumentError(f"number of views: expected a positive integer, got {n}")
    if not radius > 0:
        raise BadArgumentError(f"camera radius: expected > 0, got {radius}")


# --- projection and back-projection --------------------------------------------------------------------
def project(points_world, intrinsics: Intrinsics, cam_from_world) -> tuple[np.ndarray, np.ndarray]:
    """World points (N, 3) -> pixels (N, 2) (OpenCV convention) and z-depth (N,) in the camera."""
    return intrinsics.project_cam(transform_points(as_rigid(cam_from_world, "cam_from_world"), points_world))


def backproject_depth(depth, intrinsics: Intrinsics, cam_from_world, mask=None, return_pixels: bool = False):
    """Z-depth map (H, W) -> world points (N, 3) of the valid pixels (finite, > 0, and ``mask`` where given).

    The pixel grid comes from ``Intrinsics.pixel_grid`` (u = column, v = row), so rows and columns cannot be
    swapped by accident. With ``return_pixels`` also returns the (N, 2) pixel coordinates (u, v).
    """
    depth = np.asarray(depth)
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise BadArgumentError(f"depth map: expected shape (H, W) = ({intrinsics.height}, {intrinsics.width}) "
                               f"to match the intrinsics, got {depth.shape}")
    T = as_rigid(cam_from_world, "cam_from_world")
    valid = valid_depth_mask(depth)
    if mask is not None:
        mask = np.asarray(mask, bool)
        if mask.shape != depth.shape:
            raise BadArgumentError(f"mask: expected shape {depth.shape}, got {mask.shape}")
        valid &= mask
    uv = intrinsics.pixel_grid()[valid]
    pts = backproject_pixels(uv, depth[valid], intrinsics, T)
    return (pts, uv) if return_pixels else pts


def backproject_pixels(uv, z, intrinsics: Intrinsics, cam_from_world) -> np.ndarray:
    """Pixels (N, 2) (u = column, v = row) at z-depths (N,) -> world points (N, 3)."""
    rays = intrinsics.pixel_rays(np.asarray(uv, np.float64))
    pts_cam = rays * np.asarray(z).astype(np.float64)[:, None]
    world_from_cam = invert_rigid(as_rigid(cam_from_world, "cam_from_world"))
    return pts_cam @ world_from_cam[:3, :3].T + world_from_cam[:3, 3]


def depth_footprint(depth, intrinsics: Intrinsics) -> float | None:
    """A depth map's pixel footprint in scene units: the median of its positive depths in its central window (half
    its width and height; the whole map when that window holds under 5% of such pixels) over the mean focal length
    of ``intrinsics`` (the map's own, or another resolution's for the footprint there); None without a positive
    depth. Far background at the image borders does not move it."""
    depth = np.asarray(depth)
    H, W = depth.shape
    centre = depth[H // 4:H - H // 4, W // 4:W - W // 4]
    z = centre[centre > 0]
    if z.size < 0.05 * centre.size:
        z = depth[depth > 0]
    if not z.size:
        return None
    return float(np.median(z)) / (0.5 * (intrinsics.fx + intrinsics.fy))


def valid_depth_mask(depth) -> np.ndarray:
    """Pixels with a usable depth: finite and > 0."""
    d = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(d) & (d > 0)


@dataclass
class View:
    """One image with its camera: ``name`` (file stem), intrinsics and ``cam_from_world`` (OpenCV axes).

    Files: ``image_path`` (an absolute or working-directory path, when a reader knows it), ``image_file``
    (the image's name relative to its dataset's ``images/`` folder, e.g. ``IMG_1.JPG`` or ``train/r_0.png``;
    None = ``NAME`` plus an image suffix), and the ``mask_file`` / ``depth_file`` paths that a transforms.json
    frame gives (``mask_path``, ``depth_file_path``). ``extra`` holds a camera format's own metadata only
    (COLMAP ids, LLFF's near / far bounds, NeuS index and skew), never a file photorecon reads."""

    name: str
    intrinsics: Intrinsics
    cam_from_world: np.ndarray
    image_path: str | None = None
    extra: dict = field(default_factory=dict)
    image_file: str | None = None
    mask_file: str | None = None
    depth_file: str | None = None

    def __post_init__(self):
        self.cam_from_world = as_rigid(self.cam_from_world, f"view {self.name!r} cam_from_world")

    @property
    def center(self) -> np.ndarray:
        return camera_center(self.cam_from_world)

    @property
    def world_from_cam(self) -> np.ndarray:
        return invert_rigid(self.cam_from_world)
