"""Hole filling that leaves the observed surface as it is (the cleaning stage's ``mesh.ply``): of the rims
(``boundary_loops``), those of small, flat holes the photos saw are closed by patches (``mesh.patch``); of a
bigger hole, its notches. Which holes: each rim's radius, how far it lies off its best-fit plane
(``hole_stats``), whether the surface along it faces like that plane, and whether cameras face it.
"""
from __future__ import annotations

import numpy as np
import trimesh

from .boundary import boundary_loops, hole_stats, rim_normals, split_notches
from .patch import _drop_overused, fill_loops


# what fill_small_holes reports (and the cleaning, when it fills nothing)
NO_FILL = {"holes": None, "filled_holes": 0, "filled_notches": 0, "filled_faces": 0, "kept_open": 0, "unseen": 0}


def fill_small_holes(mesh: trimesh.Trimesh, max_radius: float, max_offplane: float = 0.5,
                     max_angle: float = 90.0, notches: bool = True, keep_open=None, centres=None,
                     min_views: int = 2, view_angle: float = 60.0, pinhole: float = 0.3) -> tuple[trimesh.Trimesh, dict]:
    """Fill the holes whose rim fits in a sphere of ``max_radius`` (scene units), lies near a plane (its farthest
    vertex off the best-fit plane at most ``max_offplane`` x that radius: a hole in a surface, not a gap between
    two sides) and along which the surface faces like that plane (the mean |cos| of the angle between the
    surface's normals at the rim and the plane's at least cos ``max_angle`` degrees: the surface around agrees,
    not a curled fringe); of a bigger hole, its notches (``split_notches``) under the same tests, and then what
    is left of it when that passes them. ``keep_open(vertices)``: True for a rim to leave as it is, notches and
    all (an object's opening at its support, for ``close_mesh``). ``centres`` (N, 3): the cameras; with them a
    hole (or notch) is filled only where at least ``min_views`` of them face it, within ``view_angle`` degrees of
    its outward normal: a gap in surface the photos saw well, not one where they saw nothing (an object's top
    seen at grazing angles from a ring of cameras, which ``mesh_closed`` closes); pinholes (a radius up to
    ``pinhole`` x ``max_radius``) are filled whatever the views. Returns the mesh and the
    facts: ``holes`` (rims found), ``filled_holes`` (whole holes), ``filled_notches``, ``filled_faces``,
    ``kept_open``, ``unseen`` (holes and notches left open for want of views)."""
    loops = boundary_loops(mesh.faces, len(mesh.vertices))
    info = {**NO_FILL, "holes": len(loops)}
    if not loops:
        out, _ = fill_loops(mesh, [])
        return out, info
    V = np.asarray(mesh.vertices, np.float64)
    F = np.asarray(mesh.faces, np.int64)
    min_agree = float(np.cos(np.radians(max_angle)))
    allv = np.concatenate(loops)
    nv = rim_normals(V, F, allv)
    normal_at = np.zeros((len(V), 3))
    normal_at[allv] = nv  # a notch's rim is part of its hole's
    starts = np.r_[0, np.cumsum([len(lp) for lp in loops])]

    cams = None if centres is None or not min_views else np.asarray(centres, np.float64).reshape(-1, 3)
    cos_view = float(np.cos(np.radians(view_angle)))
    unseen = [0]

    def seen(lp, u, st=None):
        """At least min_views cameras within view_angle of the hole's outward normal (the rim's faces' side);
        ``st``: the rim's ``hole_stats`` when the caller has them."""
        if cams is None:
            return True
        st = hole_stats(V, [lp]) if st is None else st
        if st["radius"][0] <= pinhole * max_radius:  # a pinhole: filled whatever the views
            return True
        n = st["normal"][0]
        n = n if float(u.sum(0) @ n) >= 0 else -n
        d = cams - V[lp].mean(0)
        ok = int(((d @ n) >= cos_view * np.linalg.norm(d, axis=1)).sum()) >= min_views
        unseen[0] += not ok
        return ok

    def passes(lp, u):
        st = hole_stats(V, [lp])
        agree = float(np.abs(u @ st["normal"][0]).mean())
        return (st["radius"][0] <= max_radius and st["offplane"][0] <= max_offplane and agree >= min_agree
                and seen(lp, u, st))

    fill, n_whole, n_notches, n_kept = [], 0, 0, 0
    for j, lp in enumerate(loops):
        if keep_open is not None and keep_open(lp):
            n_kept += 1
            continue
        u = nv[starts[j]:starts[j + 1]]
        if passes(lp, u):
            fill.append(lp)
            n_whole += 1
            continue
        if not notches:
            continue
        pieces, rest = split_notches(V, lp, u, max_radius, max_offplane, min_agree)
        if cams is not None:
            pieces = [pc for pc in pieces if seen(pc, normal_at[pc])]
        fill += pieces
        n_notches += len(pieces)
        if pieces and len(rest) >= 3:
            if passes(rest, normal_at[rest]):
                fill.append(rest)
    # a patch face on an edge the surface already uses twice, or run the surface's way, goes (a few per mesh)
    out = _drop_overused(fill_loops(mesh, fill)[0], new_from=len(mesh.faces))
    nf = len(out.faces) - len(mesh.faces)
    info.update(filled_holes=n_whole, filled_notches=n_notches, filled_faces=int(nf), kept_open=n_kept,
                unseen=unseen[0])
    return out, info
