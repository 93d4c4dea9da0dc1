"""What kind of capture a mesh comes from: an object (photographed from around it, standing on a table or
turntable) or an open scene (a facade, a street, a room), and the support an object stands on removed.

``--scene auto`` (the default) calls a capture an **object capture** when all of these hold, and then removes
the support plane as ``--scene object`` does (``mesh.remove_support``); otherwise the capture is **open** and
its ground stays:

1. *The cameras look at one point.* The point nearest (least squares) to every optical axis lies in front of,
   and inside the image of, at least ``MIN_SEEING`` of the cameras. Cameras side by side looking the same way
   (a street, a forward-moving video) have nearly parallel axes and no such point; cameras inside a room
   looking out have it behind them.
2. *They go around it.* Seen from that point, the cameras spread over at least ``MIN_AZIMUTH_DEG`` of azimuth
   about the support's normal (a turntable, a ring, a partial arc, a dome), not one side of a scene.
3. *A support plane lies under it* (``mesh.find_support_plane``: every camera on one side, the look-at point on
   theirs, the surface around its foot in most directions).
4. *The object is framed.* The surface above the support that holds the look-at point (its connected part
   nearest to it) lies inside the image of every camera that looks at it, for at least ``MIN_FRAMED`` of its
   area: the cameras see the object whole, with room around it. A building's wall, which a street-level
   capture's look-at point lies on, runs on past the edges of the photos.

The decision and its numbers are returned (``report.json``'s ``mesh.scene``) and logged in one line.
"""
from __future__ import annotations

import logging

import numpy as np

from .support import axes_point, find_support, remove_support

log = logging.getLogger("photorecon")

MIN_SEEING = 0.8  # fraction of the cameras that must have the look-at point in front of them and in their image
MIN_AZIMUTH_DEG = 60.0  # the cameras' spread around the look-at point, about the support's normal
MIN_FRAMED = 0.9  # fraction of the object's area inside the image of every camera that sees the look-at point
OVERHEAD_DEG = 80.0  # cameras this far above the support plane, seen from the look-at point, have no azimuth


def _views(cameras) -> list:
    return [c for c in (() if cameras is None else cameras) if hasattr(c, "cam_from_world") and hasattr(c, "intrinsics")]


def look_at_point(views) -> np.ndarray | None:
    """The point nearest (least squares) to every camera's optical axis; None with fewer than 3 views or when
    the axes are nearly parallel (the smallest eigenvalue of the normal matrix below 5% of the largest)."""
    return axes_point(views, min_views=3)


def sees(views, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """(len(views), N) bool: each point in front of each camera and inside its image (``margin``: a fraction of
    the image's size kept clear at each edge)."""
    P = np.asarray(points, float).reshape(-1, 3)
    out = np.zeros((len(views), len(P)), bool)
    for i, v in enumerate(views):
        T = np.asarray(v.cam_from_world, float)
        Xc = P @ T[:3, :3].T + T[:3, 3]
        uv, z = v.intrinsics.project_cam(Xc)
        w, h = v.intrinsics.width, v.intrinsics.height
        with np.errstate(invalid="ignore"):
            out[i] = ((z > 0) & (uv[:, 0] >= margin * w - 0.5) & (uv[:, 0] <= (1 - margin) * w - 0.5)
                      & (uv[:, 1] >= margin * h - 0.5) & (uv[:, 1] <= (1 - margin) * h - 0.5))
    return out


def camera_rig(cameras) -> dict:
    """Test 1 on the cameras alone: ``look_at`` (the point, or None), ``seeing`` (how many cameras have it in
    front and in their image), ``cameras``, and ``ok`` with a ``reason`` when not."""
    views = _views(cameras)
    out = {"cameras": len(views), "look_at": None, "seeing": 0, "ok": False}
    if len(views) < 3:
        out["reason"] = f"{len(views)} camera(s) with orientations: too few to surround an object"
        return out
    p = look_at_point(views)
    if p is None:
        out["reason"] = "the cameras' optical axes are nearly parallel (side by side or moving forward): no common point"
        return out
    seeing = int(sees(views, p[None])[:, 0].sum())
    out.update(look_at=p, seeing=seeing)
    if seeing < MIN_SEEING * len(views):
        out["reason"] = (f"the point nearest to the cameras' axes is in front of and in the image of only {seeing} "
                         f"of {len(views)} cameras: they do not look at one point")
        return out
    out["ok"] = True
    return out


def azimuth_span(centres: np.ndarray, point: np.ndarray, normal: np.ndarray) -> float:
    """Degrees of azimuth about ``normal`` through ``point`` that the camera ``centres`` cover (360 minus the
    largest gap between neighbours); cameras within 90 - OVERHEAD_DEG degrees of straight above have no azimuth
    and are left out (0 when fewer than two remain)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.asarray(centres, float) - point
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    u = u[np.abs(u @ n) < np.sin(np.radians(OVERHEAD_DEG))]
    if len(u) < 2:
        return 0.0
    e1 = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    az = np.sort(np.degrees(np.arctan2(u @ e2, u @ e1)) % 360.0)
    gaps = np.diff(np.r_[az, az[0] + 360.0])
    return float(360.0 - gaps.max())


def framed_fraction(m, keep: np.ndarray, views, point: np.ndarray, margin: float = 0.01,
                    n_samples: int = 50_000, seed: int = 0) -> float:
    """Test 4: of the Open3D mesh ``m``'s triangles where ``keep`` (the surface above the support), the connected
    part nearest to ``point``: the fraction of its area whose triangle centres lie inside the image (``margin``
    of its size clear at each edge) of every camera in ``views`` that sees ``point``."""
    import open3d as o3d

    V = np.asarray(m.vertices)
    T = np.asarray(m.triangles)[keep]
    if not len(T):
        return 0.0
    sub = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(T))
    labels, _, _ = sub.cluster_connected_triangles()
    labels = np.asarray(labels)
    tri = V[T]
    centres = tri.mean(1)
    nearest = int(np.argmin(np.linalg.norm(centres - point, axis=1)))
    part = labels == labels[nearest]
    area = 0.5 * np.linalg.norm(np.cross(tri[part, 1] - tri[part, 0], tri[part, 2] - tri[part, 0]), axis=1)
    c = centres[part]
    if len(c) > n_samples:
        pick = np.random.default_rng(seed).choice(len(c), n_samples, replace=False)
        c, area = c[pick], area[pick]
    looking = [v for v, s in zip(views, sees(views, point[None])[:, 0]) if s]
    inside = sees(looking, c, margin).all(0)
    return float(area[inside].sum() / max(area.sum(), 1e-300))


def detect_and_remove(m, cameras, voxel: float | None, cut: float, mode: str) -> dict:
    """Decide the scene (``mode`` "auto") or take it as given ("object"), and for an object remove its support
    from the Open3D mesh ``m`` in place (``mesh.remove_support``). Returns report.json's ``scene`` entry:
    ``mode``, ``detected`` ("object" or "open"), ``reason``, the tests' numbers, and ``support_removed``
    (faces, area, plane, cut) or None; logs one line."""
    info = _decide(m, cameras, voxel, cut, mode)
    _log(info)
    return info


def _decide(m, cameras, voxel: float | None, cut: float, mode: str) -> dict:
    """``detect_and_remove`` without its log line."""
    info: dict = {"mode": mode}
    if mode == "object":
        support = remove_support(m, cameras, voxel, cut, quiet=True)
        info.update(detected="object", reason="--scene object", support_removed=support)
        if support is None:
            info["reason"] += ": no support plane found (no large flat part of the surface with every camera on one " \
                              "side and the object on theirs)"
        return info
    rig = camera_rig(cameras)
    info.update(cameras=rig["cameras"], cameras_seeing_look_at=rig["seeing"])
    if not rig["ok"]:
        info.update(detected="open", reason=rig["reason"], support_removed=None)
        return info
    views = _views(cameras)
    p = rig["look_at"]
    found = find_support(m, views, voxel, cut)
    if found is None:
        info.update(detected="open", reason="no support plane under the point the cameras look at", support_removed=None)
        return info
    n, c, cut_h, drop = found
    span = azimuth_span(np.array([v.center for v in views]), p, n)
    info["azimuth_deg"] = round(span, 1)
    if span < MIN_AZIMUTH_DEG:
        info.update(detected="open", support_removed=None,
                    reason=f"the cameras see the point they look at from {span:.0f} degrees of azimuth, less than "
                           f"{MIN_AZIMUTH_DEG:.0f}: one side of a scene, not around an object")
        return info
    framed = framed_fraction(m, ~drop, views, p)
    info["framed"] = round(framed, 3)
    if framed < MIN_FRAMED:
        info.update(detected="open", support_removed=None,
                    reason=f"the surface the cameras look at runs past the edges of their images ({100 * framed:.0f}% "
                           f"of it inside every image, less than {100 * MIN_FRAMED:.0f}%): not an object they frame")
        return info
    support = remove_support(m, views, voxel, cut, found=found, quiet=True)
    info.update(detected="object", support_removed=support,
                reason=f"{rig['seeing']} of {rig['cameras']} cameras look at one point from {span:.0f} degrees around "
                       f"it, a support plane under it, the object inside their images ({100 * framed:.0f}% of it)")
    return info


def _log(info: dict) -> None:
    s = info.get("support_removed")
    did = (f"support plane removed, with everything below {s['support_cut']:.3g} above it and the support's up-facing "
           f"surface connected to it ({s['support_removed_faces']} faces, area {s['support_removed_area']:.4g})"
           if s else "nothing removed, the ground kept")
    log.info("scene: %s (%s; %s): %s", info["detected"], "detected" if info["mode"] == "auto" else "given",
             info["reason"], did)
