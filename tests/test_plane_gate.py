"""``mvs.locally_flat`` (the plane test's gate, ``MVSConfig.plane_flat_px``) on rendered depth: a plane seen at
a grazing angle is flat everywhere it is seen; a sphere seen by the same low camera is not flat where it is seen
at a grazing angle (near its outline), and flat where it faces the camera."""
import numpy as np
import trimesh

from photorecon.cameras import Intrinsics, View, look_at
from photorecon.depth.mvs import locally_flat
from photorecon.render import Renderer


def _depth(mesh, eye, target):
    intr = Intrinsics.from_fov(160, 120, 50.0)
    view = View("v", intr, look_at(np.asarray(eye, float), np.asarray(target, float)))
    r = Renderer(mesh).render(view)
    return r.depth, intr, r.normal, view


def test_plane_at_a_grazing_angle_is_flat_a_sphere_near_its_outline_is_not():
    plane = trimesh.Trimesh([[-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    d, intr, _, _ = _depth(plane, (0, -3, 0.4), (0, 0, 0))  # the ground at 7.6 degrees in the image centre
    seen = d > 0  # and its neighbours 3 px either side: not at the plane's far edge or the image border
    seen = seen & np.roll(seen, 3, 0) & np.roll(seen, -3, 0) & np.roll(seen, 3, 1) & np.roll(seen, -3, 1)
    seen[:3], seen[-3:], seen[:, :3], seen[:, -3:] = False, False, False, False
    assert seen.mean() > 0.3
    assert locally_flat(d, intr, 3, 2.0)[seen].mean() > 0.999
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
    d, intr, nrm, view = _depth(sphere, (0, -4, 0), (0, 0, 0))
    flat = locally_flat(d, intr, 3, 2.0)
    # the cosine between each pixel's normal and its ray: grazing near the outline
    rays = intr.pixel_rays(intr.pixel_grid().reshape(-1, 2)).reshape(d.shape + (3,))
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    n_cam = nrm @ view.cam_from_world[:3, :3].T
    cos = np.abs(np.einsum("hwc,hwc->hw", n_cam, rays))
    graze = (d > 0) & (cos < 0.3)
    facing = (d > 0) & (cos > 0.8)
    assert graze.sum() > 100 and facing.sum() > 1000
    assert flat[graze].mean() < 0.1, flat[graze].mean()
    assert flat[facing].mean() > 0.99
