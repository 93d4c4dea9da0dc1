"""The model's frame: the reconstruction turned upright and centred, as a glTF viewer expects it (+Y up, the
model facing +Z), without scaling.

photorecon reconstructs in the frame of the poses: the SfM solution's (an arbitrary rotation) or the given
cameras'. ``upright_frame`` finds the rigid transform ``model_from_world`` that stands the model up:

* **support plane** (an object capture: the object stands on a table or turntable, ``mesh.find_support``): the
  support plane's normal, on the cameras' side, becomes +Y; the object's base centre (the centre of its
  footprint on the plane) goes to the origin, so the object stands on the plane Y = 0.
* **camera up** (an open scene, or an object without a support plane found): up is the cameras' up (OpenCV
  camera axes: a camera's up is its -y axis). Photographers hold cameras level, so when the cameras face
  different ways up is the direction across every camera's image x axis (signed by their mean up); when they
  all face one way (or there is one camera) it is their mean up. The origin is the mesh's centre on the ground:
  the median of the vertices across up, their 1st percentile along it. This trusts the photos to be upright: a
  rig whose cameras hang upside down (the walnut captures' turntable rig) gets an upside-down model unless the
  support plane is known, so pass the cleaned mesh with the plane the cleaning removed in its metadata (or the
  mesh before the cleaning).
* **a known up** (``known_up``): where the world itself knows up (a GPS alignment's east-north-up frame), it
  replaces the cameras' up, the origin found the same way.

Forward: +Z points from the origin towards the cameras' mean position projected on the ground, so a default
glTF view (a camera on +Z looking at -Z) shows the side the photos saw. Where that is undefined (cameras all
around, their mean above the origin, or inside a room) it is the way the cameras look, reversed, and failing
that the direction to the first camera by name.

``apply`` moves a mesh into the model's frame and ``apply_views`` moves cameras with it
(``cam_from_model = cam_from_world @ inv(model_from_world)``), so photos still project onto the model.
This module imports only ``cameras``, ``errors`` and the mesh modules beside it.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np
import trimesh

from ..cameras import View, invert_rigid
from ..errors import BadArgumentError, EmptyMeshError
from .geometry import triangle_components
from .scene import MIN_AZIMUTH_DEG, MIN_FRAMED, azimuth_span, camera_rig, framed_fraction
from .support import axes_point, find_support

RULES = ("support plane", "camera up")
SCENES = ("auto", "object", "open")
MIN_RESULTANT = 0.25  # a mean of unit directions shorter than this has no direction (cameras all around)
LEVEL_SPREAD = 0.05  # cameras' image x axes spread (2nd / largest eigenvalue) at least this: they face different ways


@dataclass
class Upright:
    """The model's frame found by ``upright_frame``.

    ``model_from_world``: 4x4 rigid transform (rotation and translation, no scale) from the reconstruction's
    world to the model's frame (+Y up, +Z forward, X = Y x Z). ``rule``: "support plane", "camera up" or a
    known up's rule (the rule that set up and origin); ``reason``: why, in words. ``up_world``,
    ``forward_world``: the model's +Y and +Z in world coordinates (unit vectors); ``origin_world``: the world
    point that becomes the origin. ``plane``: the support plane (n, c) with n . X = c in world coordinates, n
    towards the cameras (None without one). ``units``: the model's length unit, the reconstruction's (nothing
    is scaled)."""

    model_from_world: np.ndarray
    rule: str
    reason: str
    up_world: np.ndarray
    forward_world: np.ndarray
    origin_world: np.ndarray
    units: str = "scene units"
    plane: tuple[np.ndarray, float] | None = field(default=None, repr=False)

    def to_dict(self) -> dict:
        """JSON-ready: the transform as 4 rows, the vectors as lists, the rule, reason and units."""
        out = {"rule": self.rule, "reason": self.reason, "units": self.units,
               "model_from_world": [[float(x) for x in row] for row in self.model_from_world],
               "up_world": [float(x) for x in self.up_world], "forward_world": [float(x) for x in self.forward_world],
               "origin_world": [float(x) for x in self.origin_world]}
        if self.plane is not None:
            out["support_plane"] = {"normal": [float(x) for x in self.plane[0]], "offset": float(self.plane[1])}
        return out


def upright_frame(mesh: trimesh.Trimesh, views: list[View] | None, scene: str = "auto", units: str = "scene units",
                  voxel: float | None = None, seed: int = 0,
                  known_up: tuple[np.ndarray, str, str] | None = None) -> Upright:
    """The rigid transform that stands ``mesh`` (in world coordinates, as reconstructed) upright in glTF's frame:
    +Y up, +Z towards the cameras, the origin at the object's base centre or the scene's centre on the ground.

    ``views``: the cameras (``View``, OpenCV axes) in the same world. ``scene``: "object" (look for the support
    plane; without one, fall back on the cameras' up), "open" (the cameras' up) or "auto" (the mesh's own
    ``metadata["scene"]["detected"]`` when the cleaning left it there; else an object when the cameras look at
    one point from at least ``scene.MIN_AZIMUTH_DEG`` degrees around it, a support plane lies under it and the
    cameras frame the object, as ``mesh.scene`` decides). A mesh whose ``metadata`` holds the support plane that
    the cleaning removed (``support_normal`` "nx,ny,nz", ``support_offset``) uses that plane. ``units``: the
    name of the reconstruction's length unit, recorded (nothing is scaled). ``voxel``: the fusion's voxel size
    (``metadata["voxel_size"]`` when None), the support plane's tolerance. ``seed``: the plane search's; the
    same inputs give the same transform. ``known_up``: (up in world coordinates, rule, reason), an up known
    from elsewhere (the east-north-up frame of a GPS alignment), used instead of the cameras' up where no support
    plane sets the frame.

    Returns an ``Upright`` (``model_from_world``, ``rule`` "support plane", "camera up" or ``known_up``'s, ``reason``,
    ``up_world``, ...). Changes nothing. Raises ``EmptyMeshError`` for a mesh without finite vertices,
    ``BadArgumentError`` for an unknown ``scene`` or when there is neither a support plane nor a camera."""
    if scene not in SCENES:
        raise BadArgumentError(f"upright frame: scene expected one of {', '.join(SCENES)}, got {scene!r}")
    if not isinstance(units, str) or not units.strip():
        raise BadArgumentError(f"upright frame: units expected a name such as 'metres', got {units!r}")
    V = np.asarray(mesh.vertices, np.float64).reshape(-1, 3)
    F = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    finite = np.isfinite(V).all(1)
    if not finite.any():
        raise EmptyMeshError("upright frame: the mesh has no vertex (nothing to stand upright)")
    views = [v for v in (views or []) if isinstance(v, View)]
    meta = getattr(mesh, "metadata", None) or {}
    if voxel is None and isinstance(meta.get("voxel_size"), (int, float)) and meta["voxel_size"] > 0:
        voxel = float(meta["voxel_size"])

    plane, reason, keep = None, "", None
    detected = (meta.get("scene") or {}).get("detected") if isinstance(meta.get("scene"), dict) else None
    want_object = scene == "object" or (scene == "auto" and detected != "open")
    if want_object:
        plane = _metadata_plane(meta)
        if plane is not None:
            reason = "the support plane the cleaning removed (mesh metadata)"
        elif len(F) and finite.all():
            plane, reason, keep = _find_plane(V, F, views, voxel, seed, check=scene == "auto" and detected is None)
    if plane is not None:
        n, c = plane
        up = n
        origin = _base_centre(V[finite], F if finite.all() else np.zeros((0, 3), np.int64), n, c, views, voxel, keep)
        rule = "support plane"
    else:
        if known_up is not None:
            up = np.asarray(known_up[0], float).reshape(3)
            if not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
                raise BadArgumentError(f"upright frame: known up expected a direction, got {known_up[0]!r}")
            up, rule, how = up / np.linalg.norm(up), str(known_up[1]), str(known_up[2])
        elif not views:
            raise BadArgumentError("upright frame: no camera and no support plane: nothing tells which way is up")
        else:
            (up, how), rule = camera_up(views), "camera up"
        h = V[finite] @ up
        origin = np.median(V[finite], axis=0)
        origin += (float(np.percentile(h, 1)) - float(origin @ up)) * up
        reason = (f"{reason}; " if reason else "") + how
    forward = _forward(up, origin, views)
    x = np.cross(up, forward)
    R = np.stack([x, up, forward])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ origin
    return Upright(T, rule, reason, up.copy(), forward, origin, units.strip(), plane)


def camera_up(views: list[View]) -> tuple[np.ndarray, str]:
    """The cameras' up in world coordinates (unit) and how it was found: the direction across every camera's
    image x axis (the least-squares normal of the x axes), signed by the cameras' mean up (-y), when the x axes
    spread (cameras facing different ways); else the mean up itself."""
    if not views:
        raise BadArgumentError("camera up: no camera")
    Rs = np.stack([np.asarray(v.cam_from_world, float)[:3, :3] for v in views])
    ups = -Rs[:, 1]  # camera -y in world coordinates
    mean = ups.mean(0)
    if np.linalg.norm(mean) < 1e-9:
        raise BadArgumentError(f"camera up: the {len(views)} cameras' up directions cancel out (half of them upside "
                               "down): no common up")
    mean /= np.linalg.norm(mean)
    xs = Rs[:, 0]
    w, E = np.linalg.eigh(xs.T @ xs)
    if len(views) >= 2 and w[1] >= LEVEL_SPREAD * w[2]:
        up = E[:, 0] * (1.0 if E[:, 0] @ mean >= 0 else -1.0)
        if np.degrees(np.arccos(np.clip(up @ mean, -1, 1))) < 60.0:  # the cameras are level, not rolled at random
            return up / np.linalg.norm(up), (f"the cameras' up: across the image x axes of {len(views)} cameras "
                                             "facing different ways")
    return mean, f"the cameras' up: the mean up of {len(views)} camera(s)"


def apply(model_from_world: np.ndarray, mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A copy of ``mesh`` moved by the rigid ``model_from_world`` (vertices, normals; colours and faces kept).
    A support plane in its metadata (``support_normal``, ``support_offset``) moves with it."""
    T = _rigid(model_from_world)
    out = mesh.copy()
    out.apply_transform(T)
    meta = dict(getattr(mesh, "metadata", None) or {})
    plane = _metadata_plane(meta)
    if plane is not None:
        n2 = T[:3, :3] @ plane[0]
        meta["support_normal"] = ",".join(f"{x:.5f}" for x in n2)
        meta["support_offset"] = float(plane[1] + n2 @ T[:3, 3])
    out.metadata = meta
    return out


def apply_views(model_from_world: np.ndarray, views: list[View]) -> list[View]:
    """Copies of ``views`` in the model's frame: ``cam_from_model = cam_from_world @ inv(model_from_world)``
    (images, intrinsics, names kept)."""
    inv = invert_rigid(_rigid(model_from_world))
    return [replace(v, cam_from_world=np.asarray(v.cam_from_world, float) @ inv, extra=dict(v.extra)) for v in views]


# --- internals -----------------------------------------------------------------------------------------------
def _rigid(T) -> np.ndarray:
    T = np.asarray(T, float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise BadArgumentError(f"model_from_world: expected a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0 or np.abs(T[3] - [0, 0, 0, 1]).max() > 1e-9:
        raise BadArgumentError("model_from_world: expected a rigid transform (a rotation and a translation)")
    return T


def _metadata_plane(meta: dict) -> tuple[np.ndarray, float] | None:
    """The support plane (n, c) that the cleaning recorded in a mesh's metadata, or None."""
    n, c = meta.get("support_normal"), meta.get("support_offset")
    if n is None or c is None:
        return None
    try:
        n = np.array([float(x) for x in (n.split(",") if isinstance(n, str) else n)], float)
        c = float(c)
    except (TypeError, ValueError):
        return None
    if n.shape != (3,) or not np.isfinite(n).all() or not np.isfinite(c) or np.linalg.norm(n) < 1e-9:
        return None
    s = np.linalg.norm(n)
    return n / s, c / s


def _arrays(V: np.ndarray, F: np.ndarray) -> SimpleNamespace:
    """(V, F) in the shape the support search reads (an Open3D mesh's ``vertices`` and ``triangles``)."""
    return SimpleNamespace(vertices=V, triangles=F)


def _find_plane(V, F, views, voxel, seed, check: bool):
    """(plane (n, c) or None, reason, per face True off the support or None): the support plane of (V, F) with
    ``find_support``; with ``check``, only for an object capture by ``mesh.scene``'s tests (cameras looking at
    one point from around it, the object framed)."""
    if len(views) < 2:
        return None, f"no support plane looked for: {len(views)} camera(s), too few to tell an object's support", None
    rig = None
    if check:
        rig = camera_rig(views)
        if not rig["ok"]:
            return None, f"an open scene: {rig['reason']}", None
    m = _arrays(V, F)
    found = find_support(m, views, voxel, seed=seed)
    if found is None:
        return None, ("no support plane found (no large flat part of the surface with every camera on one side "
                      "and the object on theirs)"), None
    n, c, _, drop = found
    if check:
        span = azimuth_span(np.array([v.center for v in views]), rig["look_at"], n)
        if span < MIN_AZIMUTH_DEG:
            return None, (f"an open scene: the cameras see the point they look at from {span:.0f} degrees of "
                          f"azimuth, less than {MIN_AZIMUTH_DEG:.0f}"), None
        framed = framed_fraction(m, ~drop, views, rig["look_at"])
        if framed < MIN_FRAMED:
            return None, (f"an open scene: the surface the cameras look at runs past the edges of their images "
                          f"({100 * framed:.0f}% inside)"), None
    return ((np.asarray(n, float), float(c)), f"the support plane under the object ({len(views)} cameras on its side)",
            ~np.asarray(drop, bool))


def _base_centre(V, F, n, c, views, voxel, keep=None) -> np.ndarray:
    """The object's base centre on the plane n . X = c: the centroid of the convex hull of the object's
    footprint (its vertices projected onto the plane). The object is the connected part of the surface above
    the plane (the faces where ``keep``, the support search's faces off the support, or those with every corner
    above the plane) nearest to the point the cameras look at (the faces' median without such a point); the
    vertices above the plane without faces. Falls back on the foot of that point, then of the vertices' median."""
    h = V @ n - c
    extent = float(np.linalg.norm(np.percentile(V, 99, 0) - np.percentile(V, 1, 0))) if len(V) else 0.0
    tol = 2 * float(voxel) if voxel else max(extent, 1e-12) / 500
    target = _look_at(views)
    above = h > tol
    pts = V[above]
    if len(F):
        keep = above[F].all(1) if keep is None else np.asarray(keep, bool)
        if keep.any():
            Fk = F[keep]
            labels = triangle_components(V, Fk)[0]
            centres = V[Fk].mean(1)
            ref = target if target is not None else np.median(centres, axis=0)
            part = labels == labels[int(np.argmin(np.linalg.norm(centres - ref, axis=1)))]
            pts = V[np.unique(Fk[part])]
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    foot0 = (c * n) if target is None else target - (target @ n - c) * n
    if len(pts) >= 3:
        xy = np.stack([(pts - foot0) @ e1, (pts - foot0) @ e2], 1)
        centre = _hull_centroid(xy)
        if centre is not None:
            return foot0 + centre[0] * e1 + centre[1] * e2
    if target is not None:
        return foot0
    med = np.median(V, axis=0)
    return med - (med @ n - c) * n


def _hull_centroid(xy: np.ndarray) -> np.ndarray | None:
    """The area centroid of the 2D convex hull of ``xy`` (N, 2); None when it has no area."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(xy)
    except (QhullError, ValueError):
        return None
    P = xy[hull.vertices]  # counter-clockwise
    Q = np.roll(P, -1, axis=0)
    cross = P[:, 0] * Q[:, 1] - Q[:, 0] * P[:, 1]
    area = cross.sum() / 2
    if not abs(area) > 1e-300:
        return None
    return ((P + Q) * cross[:, None]).sum(0) / (6 * area)


def _look_at(views) -> np.ndarray | None:
    return axes_point(views, min_views=2) if len(views) >= 2 else None


def _horizontal(d: np.ndarray, up: np.ndarray) -> np.ndarray:
    return d - (d @ up) * up


def _forward(up: np.ndarray, origin: np.ndarray, views: list[View]) -> np.ndarray:
    """The model's +Z (unit, across ``up``): towards the cameras' mean position seen from ``origin``, on the
    ground; where the cameras are all around (their mean direction shorter than ``MIN_RESULTANT``), against
    the way they look; failing that, towards the first camera by name; with no camera, the world axis most
    across ``up``."""
    if views:
        C = np.array([v.center for v in views])
        dirs = np.array([_horizontal(p - origin, up) for p in C])
        lens = np.linalg.norm(dirs, axis=1)
        ok = lens > 1e-9 * max(float(lens.max()), 1e-300)
        if ok.any():
            mean = (dirs[ok] / lens[ok, None]).mean(0)
            if np.linalg.norm(mean) >= MIN_RESULTANT:
                return mean / np.linalg.norm(mean)
        looks = np.array([-_horizontal(np.asarray(v.cam_from_world, float)[2, :3], up) for v in views])
        llen = np.linalg.norm(looks, axis=1)
        good = llen > 1e-6
        if good.any():
            mean = (looks[good] / llen[good, None]).mean(0)
            if np.linalg.norm(mean) >= MIN_RESULTANT:
                return mean / np.linalg.norm(mean)
        first = min(range(len(views)), key=lambda i: views[i].name)
        if ok[first]:
            return dirs[first] / lens[first]
        if good[first]:
            return looks[first] / llen[first]
    axis = np.eye(3)[int(np.argmin(np.abs(up)))]
    d = _horizontal(axis, up)
    return d / np.linalg.norm(d)
