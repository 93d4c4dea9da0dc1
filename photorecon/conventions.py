"""The only place camera-axis flips and world re-orientations live.

photorecon's internal pose is ``cam_from_world`` (4x4, float64, world -> camera) in **OpenCV axes**
(x right, y down, z forward). Every function here converts between that and one other convention, in both
directions, and validates its input (``ValueError`` subclass ``BadArgumentError`` on wrong shapes, NaNs or
non-orthonormal rotations).

| convention        | camera axes                    | stored pose                                   |
|-------------------|--------------------------------|-----------------------------------------------|
| OpenCV            | x right, y down, z forward     | cam_from_world [R | t]                        |
| COLMAP            | as OpenCV                      | cam_from_world as qvec (w, x, y, z) + tvec    |
| OpenGL / Blender  | x right, y up, z backward      | world_from_cam (camera looks down -z)         |
| NeRF transforms   | as OpenGL                      | transform_matrix = world_from_cam, optionally |
|                   |                                | in a re-oriented world (instant-ngp/nerfstudio)|
| PyTorch3D         | x left, y up, z forward        | row vectors: X_view = X_world @ R + T         |
| Open3D            | as OpenCV                      | extrinsic = cam_from_world                    |
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ._validate import SNAP_TOL, as_array, as_rigid, as_rotation
from .cameras import COLMAP_MODELS, Intrinsics, invert_rigid, rigid
from .errors import BadArgumentError

# OpenCV camera axes -> OpenGL camera axes (and back: the matrix is its own inverse).
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
# OpenCV camera axes -> PyTorch3D view axes (x left, y up, z forward).
P3D_FROM_CV = np.diag([-1.0, -1.0, 1.0])

# A z-up world turned into a y-up one by a proper rotation: (x, y, z) -> (x, z, -y). nerfstudio's COLMAP import
# applies exactly this; synthetic rigs use it for meshes modelled y-up (the Stanford bunny).
Y_UP_FROM_Z_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])

# World re-orientations applied by NeRF tools when they convert a COLMAP model: new_world_from_world.
#  * "none": the world is kept as it is.
#  * "instant-ngp": colmap2nerf.py swaps x and y and negates z: (x, y, z) -> (y, x, -z).
#  * "nerfstudio": colmap_utils.colmap_to_json swaps y and z and negates the new z: (x, y, z) -> (x, z, -y);
#    nerfstudio records it in the file as "applied_transform".
# Both are proper rotations (det +1). instant-ngp's later data-dependent steps (re-centring, "up" alignment,
# scaling to an average distance of 4) are not part of the fixed convention and are not applied here.
NERF_WORLDS: dict[str, np.ndarray] = {
    "none": np.eye(4),
    "instant-ngp": np.array([[0.0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]),
    "nerfstudio": rigid(Y_UP_FROM_Z_UP, np.zeros(3)),
}


# --- pixel convention ------------------------------------------------------------------------------------
# photorecon (OpenCV): the centre of the top-left pixel is (0, 0). COLMAP, nerfstudio and instant-ngp put it at
# (0.5, 0.5). These two functions are the only place that half pixel is added or removed.
COLMAP_PIXEL_SHIFT = 0.5


def opencv_from_colmap_pixels(xy):
    """Pixel coordinates (any shape, last axis (u, v) or scalars) in COLMAP's / NeRF's convention -> photorecon's."""
    return np.asarray(xy, float) - COLMAP_PIXEL_SHIFT


def colmap_from_opencv_pixels(xy):
    """Pixel coordinates in photorecon's convention -> COLMAP's / NeRF's (centre of the top-left pixel at 0.5)."""
    return np.asarray(xy, float) + COLMAP_PIXEL_SHIFT


def intrinsics_from_colmap(model: str, width: int, height: int, params) -> Intrinsics:
    """A COLMAP camera (model name, size, parameter list in COLMAP's order) -> ``Intrinsics`` (principal point
    moved to photorecon's pixel convention)."""
    if model not in COLMAP_MODELS:
        raise BadArgumentError(f"COLMAP camera model {model!r} is not supported; expected one of {sorted(COLMAP_MODELS)}")
    names = COLMAP_MODELS[model]
    params = [float(p) for p in params]
    if len(params) != len(names):
        raise BadArgumentError(f"COLMAP {model}: expected {len(names)} parameters {names}, got {len(params)}")
    p = dict(zip(names, params))
    if "f" in p:
        p["fx"] = p["fy"] = p.pop("f")
    p["cx"], p["cy"] = (float(c) for c in opencv_from_colmap_pixels([p["cx"], p["cy"]]))
    return Intrinsics(width, height, model=model, **p)


def colmap_from_intrinsics(intr: Intrinsics) -> tuple[str, int, int, list[float]]:
    """``Intrinsics`` -> (model, width, height, params) in COLMAP's parameter order and pixel convention."""
    cx, cy = (float(c) for c in colmap_from_opencv_pixels([intr.cx, intr.cy]))
    vals = {"f": intr.fx, "fx": intr.fx, "fy": intr.fy, "cx": cx, "cy": cy,
            "k1": intr.k1, "k2": intr.k2, "p1": intr.p1, "p2": intr.p2, "k3": intr.k3, "k4": intr.k4}
    return intr.model, intr.width, intr.height, [float(vals[n]) for n in COLMAP_MODELS[intr.model]]


# --- COLMAP ----------------------------------------------------------------------------------------------
def quat_from_rotation(R) -> np.ndarray:
    """3x3 rotation -> unit quaternion (w, x, y, z) with w >= 0 (COLMAP's order)."""
    q = Rotation.from_matrix(as_rotation(R)).as_quat(scalar_first=True)
    return q if q[0] >= 0 else -q


def rotation_from_quat(qvec) -> np.ndarray:
    """Quaternion (w, x, y, z) -> 3x3 rotation. The quaternion must have unit norm to ``SNAP_TOL`` (rounded
    camera files); it is normalised."""
    q = as_array(qvec, (4,), "qvec (w, x, y, z)")
    n = np.linalg.norm(q)
    if abs(n - 1) > SNAP_TOL:
        raise BadArgumentError(f"qvec (w, x, y, z): expected a unit quaternion, got norm {n:.6g}")
    return Rotation.from_quat(q / n, scalar_first=True).as_matrix()


def colmap_from_opencv(cam_from_world) -> tuple[np.ndarray, np.ndarray]:
    """cam_from_world (4x4) -> COLMAP (qvec (w, x, y, z), tvec), both world-to-camera."""
    T = as_rigid(cam_from_world, "cam_from_world")
    return quat_from_rotation(T[:3, :3]), T[:3, 3].copy()


def opencv_from_colmap(qvec, tvec) -> np.ndarray:
    """COLMAP qvec (w, x, y, z) + tvec -> cam_from_world (4x4)."""
    return rigid(rotation_from_quat(qvec), as_array(tvec, (3,), "tvec"))


# --- OpenGL / Blender ------------------------------------------------------------------------------------
def opengl_from_opencv(cam_from_world) -> np.ndarray:
    """cam_from_world (OpenCV) -> world_from_cam in OpenGL/Blender camera axes (camera looks down -z, +y up)."""
    return invert_rigid(as_rigid(cam_from_world, "cam_from_world")) @ GL_FROM_CV


def opencv_from_opengl(world_from_cam_gl) -> np.ndarray:
    """world_from_cam in OpenGL/Blender camera axes -> cam_from_world (OpenCV)."""
    return invert_rigid(as_rigid(world_from_cam_gl, "world_from_cam (OpenGL)") @ GL_FROM_CV)


blender_from_opencv = opengl_from_opencv
opencv_from_blender = opencv_from_opengl


# --- NeRF transforms.json --------------------------------------------------------------------------------
def _nerf_world(world: str) -> np.ndarray:
    if world not in NERF_WORLDS:
        raise BadArgumentError(f"NeRF world orientation: expected one of {sorted(NERF_WORLDS)}, got {world!r}")
    return NERF_WORLDS[world]


def nerf_from_opencv(cam_from_world, world: str = "none") -> np.ndarray:
    """cam_from_world (OpenCV) -> transforms.json ``transform_matrix`` (camera-to-world, OpenGL camera axes),
    in the world re-oriented by the named ``world`` convention (see ``NERF_WORLDS``)."""
    return _nerf_world(world) @ opengl_from_opencv(cam_from_world)


def opencv_from_nerf(transform_matrix, world: str = "none") -> np.ndarray:
    """transforms.json ``transform_matrix`` (with its ``world`` re-orientation) -> cam_from_world (OpenCV)."""
    M = as_rigid(transform_matrix, "transform_matrix")
    return opencv_from_opengl(_nerf_world(world).T @ M)


# --- PyTorch3D --------------------------------------------------------------------------------------------
def pytorch3d_from_opencv(cam_from_world) -> tuple[np.ndarray, np.ndarray]:
    """cam_from_world (OpenCV) -> PyTorch3D (R (3, 3), T (3,)) with ``X_view = X_world @ R + T`` (row vectors),
    view axes +x left, +y up, +z forward."""
    T4 = as_rigid(cam_from_world, "cam_from_world")
    R_view = P3D_FROM_CV @ T4[:3, :3]  # column-vector rotation world -> PyTorch3D view
    return R_view.T.copy(), P3D_FROM_CV @ T4[:3, 3]


def opencv_from_pytorch3d(R, T) -> np.ndarray:
    """PyTorch3D (R, T) (row-vector convention) -> cam_from_world (OpenCV)."""
    R = as_rotation(R, "PyTorch3D R")
    T = as_array(T, (3,), "PyTorch3D T")
    return rigid(P3D_FROM_CV @ R.T, P3D_FROM_CV @ T)


def pytorch3d_intrinsics(intr: Intrinsics, space: str = "screen") -> np.ndarray:
    """The 4x4 ``K`` of PyTorch3D's ``PerspectiveCameras`` (the article's
    ``[[fx,0,px,0],[0,fy,py,0],[0,0,0,1],[0,0,1,0]]``), in ``space`` 'screen' or 'ndc'.

    * screen (``in_ndc=False``): focal lengths in pixels; the principal point in PyTorch3D's screen
      coordinates, where pixel corners are integers, i.e. ``px = cx + 0.5`` (OpenCV's cx is a pixel centre).
    * ndc: ``s = min(W, H) / 2``; ``fx_ndc = fx / s``, ``px_ndc = -(px - W / 2) / s`` (NDC +x points left).
      This is exact to the sub-pixel; ``pytorch3d.utils.cameras_from_opencv_projection`` omits the 0.5 px.

    Distortion is not representable; distorted intrinsics are refused.
    """
    if intr.has_distortion:
        raise BadArgumentError("PyTorch3D cameras have no lens distortion: undistort the images first")
    fx, fy, px, py = intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5
    if space == "ndc":
        s = min(intr.width, intr.height) / 2.0
        fx, fy = fx / s, fy / s
        px, py = -(px - intr.width / 2.0) / s, -(py - intr.height / 2.0) / s
    elif space != "screen":
        raise BadArgumentError(f"PyTorch3D space: expected 'screen' or 'ndc', got {space!r}")
    return np.array([[fx, 0, px, 0], [0, fy, py, 0], [0, 0, 0, 1], [0, 0, 1, 0]], dtype=np.float64)


def intrinsics_from_pytorch3d(K4, width: int, height: int, space: str = "screen") -> Intrinsics:
    """Inverse of ``pytorch3d_intrinsics``."""
    K4 = as_array(K4, (4, 4), "PyTorch3D K")
    fx, fy, px, py = K4[0, 0], K4[1, 1], K4[0, 2], K4[1, 2]
    if space == "ndc":
        s = min(width, height) / 2.0
        fx, fy = fx * s, fy * s
        px, py = width / 2.0 - px * s, height / 2.0 - py * s
    elif space != "screen":
        raise BadArgumentError(f"PyTorch3D space: expected 'screen' or 'ndc', got {space!r}")
    return Intrinsics(width, height, fx, fy, px - 0.5, py - 0.5)


# --- Open3D ------------------------------------------------------------------------------------------------
def open3d_extrinsic(cam_from_world) -> np.ndarray:
    """Open3D's ``extrinsic`` is world -> camera in OpenCV axes: the same matrix (validated copy)."""
    return as_rigid(cam_from_world, "cam_from_world").copy()


def opencv_from_open3d(extrinsic) -> np.ndarray:
    return as_rigid(extrinsic, "Open3D extrinsic").copy()


def open3d_intrinsic(intr: Intrinsics):
    """``open3d.camera.PinholeCameraIntrinsic(w, h, fx, fy, cx, cy)`` (Open3D uses OpenCV's pixel centres)."""
    import open3d as o3d

    if intr.has_distortion:
        raise BadArgumentError("Open3D pinhole intrinsics have no lens distortion: undistort the images first")
    return o3d.camera.PinholeCameraIntrinsic(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy)


def intrinsics_from_open3d(pinhole) -> Intrinsics:
    K = np.asarray(pinhole.intrinsic_matrix)
    return Intrinsics.from_K(K, pinhole.width, pinhole.height)
