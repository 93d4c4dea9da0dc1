"""Metric scale: ArUco markers of known size, or the photos' EXIF GPS, turn an SfM model's arbitrary units
into metres.

* ``marker_scale``: detects ArUco markers (OpenCV's ``cv2.aruco.ArucoDetector``) in the undistorted images,
  triangulates each marker corner from every view that sees it with the model's (fixed) cameras (linear DLT on
  normalised image coordinates, so distorted cameras work too) and returns the factor ``s`` that makes the mean
  marker edge measure the given size, with the edges' relative spread as a sanity figure.
* ``gps_alignment``: reads GPSLatitude / GPSLongitude / GPSAltitude from the photos' EXIF (Pillow), converts
  them to local east-north-up metres around the first photo with GPS (WGS84 -> ECEF -> ENU) and fits a Sim3
  (``transform.umeyama``) from the camera centres to those positions. Needs >= 3 photos with GPS whose positions
  are not (nearly) on one line.
* ``apply_similarity``: the model in the world ``X' = s R X + t``. Cameras keep their images: every camera
  frame is scaled by ``s`` too, so ``cam_from_world' = [R_c R^T | s t_c - R_c R^T t]`` and a point's camera
  coordinates are multiplied by ``s`` (same pixel, depth times ``s``).
* ``scale_output``: the poses stage's hook: reads ``OUT/sparse/0``, applies the marker scale (if
  ``--marker-size``) or else the GPS alignment (if the photos have GPS), rewrites ``OUT/sparse/0`` and
  ``OUT/transforms.json`` and returns the ``units`` ("metre" or "arbitrary") and what was measured.

Both alignments are absolute (computed from the model as it is), so applying them to an already scaled model
is a no-op: a re-run never scales twice.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..cameras import rigid
from ..errors import BadArgumentError, InputDataError
from ..layout import Layout
from ..io.colmap_text import SparseModel
from ..config_checks import check_config
from ..transform import umeyama

log = logging.getLogger("photorecon")

UNITS = ("metre", "arbitrary")


@dataclass
class ScaleConfig:
    """Settings of the metric-scale step (after the poses; ``photorecon sfm`` and ``reconstruct``)."""

    marker_size: float | None = field(default=None, metadata={"help": "edge length of the ArUco markers in the scene (the black square's outer edge), metres: the model is scaled so that they measure it", "range": (0.0, 1e6), "exclusive_min": True})
    marker_dict: str = field(default="4x4_50", metadata={"help": "ArUco dictionary of the markers: 4x4_50, 5x5_100, 6x6_250, 7x7_1000, original, apriltag_36h11, ... (OpenCV's DICT_* names, case-insensitive)", "metavar": "NAME"})
    gps: bool = field(default=True, metadata={"help": "without --marker-size: align the model to east-north-up metres around the first photo with the photos' EXIF GPS (>= 3 photos, not in a line)"})

    def __post_init__(self):
        check_config(self)  # types and ranges as declared (photorecon.config_checks)
        check_marker_size(self.marker_size)
        aruco_dictionary_id(self.marker_dict)  # an unknown name fails before anything runs


def check_marker_size(size) -> None:
    if size is None:
        return
    if not (isinstance(size, (int, float)) and math.isfinite(size) and size > 0):
        raise BadArgumentError(f"--marker-size: expected a marker edge length > 0 in metres, got {size}")


def aruco_dictionary_id(name: str) -> int:
    """OpenCV's dictionary constant for ``name`` ("4x4_50", "DICT_4X4_50", "original", "apriltag_36h11")."""
    import cv2

    key = "DICT_" + str(name).upper().removeprefix("DICT_")
    if key == "DICT_ORIGINAL":
        key = "DICT_ARUCO_ORIGINAL"
    if not hasattr(cv2.aruco, key):
        known = sorted(k.removeprefix("DICT_").lower() for k in dir(cv2.aruco)
                       if k.startswith("DICT_") and isinstance(getattr(cv2.aruco, k), int))
        raise BadArgumentError(f"--marker-dict: expected an ArUco dictionary ({', '.join(known[:8])}, ...), got {name!r}")
    return int(getattr(cv2.aruco, key))


# --- similarity transforms of a model ---------------------------------------------------------------------
def apply_similarity(model: SparseModel, s: float, R=None, t=None) -> SparseModel:
    """``model`` in the world ``X' = s R X + t`` (s > 0, R a rotation, t a translation (3,)).

    Derivation: ``X_c = R_c X + t_c`` and ``X = R^T (X' - t) / s``; camera frames scale with the world, so
    ``X_c' = s X_c = R_c R^T X' + (s t_c - R_c R^T t)``. Pixels are unchanged (``X_c'`` is parallel to ``X_c``);
    depths are multiplied by ``s``. Observations and point ids are kept."""
    if not (math.isfinite(s) and s > 0):
        raise BadArgumentError(f"similarity scale: expected a finite s > 0, got {s}")
    R = np.eye(3) if R is None else np.asarray(R, float)
    t = np.zeros(3) if t is None else np.asarray(t, float).reshape(3)
    if R.shape != (3, 3) or np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise BadArgumentError(f"similarity rotation: expected a 3x3 rotation matrix, got {R.tolist()}")
    views = []
    for v in model.views:
        Rc, tc = v.cam_from_world[:3, :3], v.cam_from_world[:3, 3]
        Rn = Rc @ R.T
        views.append(dataclasses.replace(v, cam_from_world=rigid(Rn, s * tc - Rn @ t), extra=dict(v.extra)))
    points = s * np.asarray(model.points, float).reshape(-1, 3) @ R.T + t
    return SparseModel(views, points, model.colors, model.point_ids, model.errors, model.observations)


# --- markers -------------------------------------------------------------------------------------------------
@dataclass
class ScaleResult:
    """What ``marker_scale`` measured. ``scale`` is None (and ``reason`` says why) when it could not measure."""

    scale: float | None
    markers: int = 0  # markers triangulated
    edges: list[float] = field(default_factory=list)  # their edge lengths in model units
    spread: float | None = None  # std / mean of the edges (relative); a bent or misdetected marker shows here
    views: int = 0  # views in which a marker was detected
    reprojection_px: float | None = None  # mean reprojection error of the triangulated corners
    reason: str = ""

    def as_dict(self) -> dict:
        return {"scale": self.scale, "markers": self.markers, "views_with_markers": self.views,
                "edge_mean_model_units": float(np.mean(self.edges)) if self.edges else None,
                "edge_spread_rel": self.spread, "reprojection_px": self.reprojection_px,
                **({"reason": self.reason} if self.reason else {})}


def detect_markers(image: np.ndarray, dictionary: str) -> dict[int, np.ndarray]:
    """ArUco markers in an 8-bit image: id -> (4, 2) corner pixels (OpenCV convention, clockwise from the
    marker's top-left). An id found twice in the image is dropped (ambiguous)."""
    import cv2

    det_params = cv2.aruco.DetectorParameters()
    det_params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(aruco_dictionary_id(dictionary)), det_params)
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return {}
    ids = ids.ravel().tolist()
    return {i: c.reshape(4, 2).astype(np.float64) for i, c in zip(ids, corners) if ids.count(i) == 1}


def triangulate_dlt(rays: np.ndarray, cams: Sequence[np.ndarray]) -> np.ndarray:
    """World point from normalised rays (N, 3) with z = 1 in the cameras ``cams`` (N 4x4 cam_from_world):
    linear DLT, rows ``x P3 - P1`` and ``y P3 - P2``."""
    A = []
    for (x, y, _), T in zip(rays, cams):
        P = T[:3]
        A.append(x * P[2] - P[0])
        A.append(y * P[2] - P[1])
    _, _, Vt = np.linalg.svd(np.array(A))
    X = Vt[-1]
    return X[:3] / X[3]


def _image_paths(model: SparseModel, image_paths) -> list[Path | None]:
    """One path (or None) per view, from a sequence aligned with the views or a mapping name -> path."""
    if isinstance(image_paths, Mapping):
        return [Path(image_paths[v.name]) if image_paths.get(v.name) else None for v in model.views]
    paths = list(image_paths)
    if len(paths) != len(model.views):
        raise BadArgumentError(f"image paths: expected one per view ({len(model.views)}), got {len(paths)}")
    return [Path(p) if p else None for p in paths]


def marker_scale(model: SparseModel, image_paths, size: float, dictionary: str = "4x4_50",
                 max_reprojection_px: float = 3.0) -> ScaleResult:
    """Scale factor ``s`` for ``apply_similarity`` that makes ArUco markers of edge ``size`` (metres) measure it.

    ``image_paths``: the views' images (a list aligned with ``model.views`` or a mapping view name -> path),
    taken with the model's cameras (undistorted images with pinhole cameras, or distorted ones with theirs).
    A corner is triangulated when >= 2 views see its marker; a marker counts when all 4 corners reproject
    within ``max_reprojection_px``. Returns ``ScaleResult(scale=None, reason=...)`` when no marker counts."""
    from ..cameras import project
    from ..io.images import read_image

    check_marker_size(size)
    paths = _image_paths(model, image_paths)
    seen: dict[int, list[tuple[int, np.ndarray]]] = {}
    n_views = 0
    for i, (v, p) in enumerate(zip(model.views, paths)):
        if p is None or not p.is_file():
            continue
        found = detect_markers(read_image(p), dictionary)
        n_views += bool(found)
        for mid, corners in found.items():
            seen.setdefault(mid, []).append((i, corners))
    if not seen:
        return ScaleResult(None, reason=f"no {dictionary} ArUco marker detected in {len(paths)} images")
    edges, reproj, n_markers, why = [], [], 0, []
    for mid, obs in sorted(seen.items()):
        if len(obs) < 2:
            why.append(f"marker {mid} seen in 1 view")
            continue
        cams = [model.views[i].cam_from_world for i, _ in obs]
        corners3d, errs = [], []
        for k in range(4):
            rays = np.array([model.views[i].intrinsics.pixel_rays(c[k:k + 1])[0] for i, c in obs])
            X = triangulate_dlt(rays, cams)
            for (i, c) in obs:
                uv, z = project(X[None], model.views[i].intrinsics, model.views[i].cam_from_world)
                errs.append(float(np.linalg.norm(uv[0] - c[k])) if z[0] > 0 else math.inf)
            corners3d.append(X)
        if max(errs) > max_reprojection_px:
            why.append(f"marker {mid} reprojects {max(errs):.1f} px off")
            continue
        C = np.array(corners3d)
        edges += [float(np.linalg.norm(C[(k + 1) % 4] - C[k])) for k in range(4)]
        reproj += errs
        n_markers += 1
    if not n_markers:
        return ScaleResult(None, views=n_views, reason="no marker triangulated: " + "; ".join(why))
    mean_edge = float(np.mean(edges))
    return ScaleResult(size / mean_edge, n_markers, edges, float(np.std(edges) / mean_edge), n_views,
                       float(np.mean(reproj)))


# --- GPS -----------------------------------------------------------------------------------------------------
WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563
WGS84_E2 = WGS84_F * (2 - WGS84_F)


def ecef_from_geodetic(lat_deg, lon_deg, alt_m) -> np.ndarray:
    """WGS84 latitude, longitude (degrees) and ellipsoidal height (m) -> ECEF (N, 3) metres."""
    lat, lon = np.radians(np.asarray(lat_deg, float)), np.radians(np.asarray(lon_deg, float))
    h = np.asarray(alt_m, float)
    N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(N + h) * np.cos(lat) * np.cos(lon), (N + h) * np.cos(lat) * np.sin(lon),
                     (N * (1 - WGS84_E2) + h) * np.sin(lat)], axis=-1)


def geodetic_from_ecef(xyz) -> np.ndarray:
    """ECEF (N, 3) metres -> (N, 3) latitude, longitude (degrees), height (m); fixed-point iteration."""
    xyz = np.atleast_2d(np.asarray(xyz, float))
    x, y, z = xyz.T
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - WGS84_E2))
    for _ in range(10):
        N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - N
        lat = np.arctan2(z, p * (1 - WGS84_E2 * N / (N + h)))
    N = WGS84_A / np.sqrt(1 - WGS84_E2 * np.sin(lat) ** 2)
    h = p / np.cos(lat) - N
    return np.stack([np.degrees(lat), np.degrees(lon), h], axis=1)


def enu_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rows: east, north, up unit vectors in ECEF at (lat, lon)."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    return np.array([[-math.sin(lo), math.cos(lo), 0.0],
                     [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
                     [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)]])


def enu_from_geodetic(lla, origin) -> np.ndarray:
    """(N, 3) latitude, longitude, height -> east, north, up metres around ``origin`` (lat, lon, height)."""
    lla = np.atleast_2d(np.asarray(lla, float))
    o = np.asarray(origin, float)
    d = ecef_from_geodetic(lla[:, 0], lla[:, 1], lla[:, 2]) - ecef_from_geodetic(o[0], o[1], o[2])
    return d @ enu_rotation(o[0], o[1]).T


def geodetic_from_enu(enu, origin) -> np.ndarray:
    """Inverse of ``enu_from_geodetic``."""
    o = np.asarray(origin, float)
    xyz = np.atleast_2d(np.asarray(enu, float)) @ enu_rotation(o[0], o[1]) + ecef_from_geodetic(o[0], o[1], o[2])
    return geodetic_from_ecef(xyz)


def read_gps(path: str | Path) -> tuple[float, float, float] | None:
    """(latitude, longitude, altitude) in degrees and metres from a photo's EXIF GPS tags, or None.
    A missing altitude reads as 0 m (then the fit's vertical is only as good as the photos' spread)."""
    from ..io.images import open_photo

    try:
        with open_photo(path) as im:
            gps = im.getexif().get_ifd(0x8825)
    except Exception:  # unreadable EXIF: treated as no GPS
        return None
    if not gps or 2 not in gps or 4 not in gps:
        return None

    def deg(v) -> float:
        d, m, s = (float(x) for x in v)
        return d + m / 60 + s / 3600

    def ref(v) -> str:
        return (v.decode(errors="ignore") if isinstance(v, bytes) else str(v)).strip("\x00 ").upper()

    try:
        lat = deg(gps[2]) * (-1 if ref(gps.get(1, "N")) == "S" else 1)
        lon = deg(gps[4]) * (-1 if ref(gps.get(3, "E")) == "W" else 1)
        alt = float(gps.get(6, 0.0))
        below = gps.get(5, 0)
        if (below[0] if isinstance(below, bytes) and below else below) == 1:
            alt = -alt
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt) and abs(lat) <= 90 and abs(lon) <= 180):
        return None
    return lat, lon, alt


@dataclass
class Sim3:
    """``X_enu = s R X_model + t``; ``origin`` = the (lat, lon, height) of the ENU frame's origin."""

    s: float
    R: np.ndarray
    t: np.ndarray
    origin: tuple[float, float, float]
    photos: int  # photos with GPS used in the fit
    rms_m: float  # RMS distance between the aligned camera centres and their GPS positions

    def as_dict(self) -> dict:
        return {"scale": self.s, "photos_with_gps": self.photos, "rms_m": self.rms_m,
                "enu_origin_lat_lon_alt": list(self.origin)}


def gps_alignment(model: SparseModel, image_paths, min_spread_m: float = 0.5) -> Sim3 | None:
    """Sim3 from the model's world to east-north-up metres around the first view's photo with GPS, fitted on
    the camera centres (``image_paths``: the photos with their EXIF, aligned with the views or a mapping
    name -> path). None, with a warning, when fewer than 3 photos have GPS or their positions (or the camera
    centres) lie nearly on a line (the rotation about it is then unknown)."""
    paths = _image_paths(model, image_paths)
    fixes = [(v, read_gps(p)) for v, p in zip(model.views, paths) if p is not None and p.is_file()]
    fixes = [(v, g) for v, g in fixes if g is not None]
    if not fixes:
        return None
    if len(fixes) < 3:
        log.warning("metric scale: only %d of %d photos have EXIF GPS; need at least 3 (units stay arbitrary)",
                    len(fixes), len(model.views))
        return None
    origin = fixes[0][1]
    enu = enu_from_geodetic([g for _, g in fixes], origin)
    centres = np.array([v.center for v, _ in fixes])
    sv = np.linalg.svd(enu - enu.mean(0), compute_uv=False)
    sc = np.linalg.svd(centres - centres.mean(0), compute_uv=False)
    if sv[1] < max(min_spread_m, 0.05 * sv[0]) * math.sqrt(len(fixes)) or sc[1] < 0.05 * sc[0]:
        log.warning("metric scale: the %d GPS positions lie nearly on a line (spread %.2f m x %.2f m); cannot "
                    "fix the orientation (units stay arbitrary)", len(fixes), *(sv[:2] / math.sqrt(len(fixes))))
        return None
    s, R, t = umeyama(centres, enu)
    rms = float(np.sqrt(np.mean(np.sum((s * centres @ R.T + t - enu) ** 2, axis=1))))
    return Sim3(float(s), R, t, tuple(float(x) for x in origin), len(fixes), rms)


# --- the poses stage's hook ------------------------------------------------------------------------------
def given_units(poses: str | Path | None) -> str:
    """Units of given cameras: the ``units`` key of a transforms.json written by photorecon (the file itself,
    or ``transforms.json`` in the folder / beside its ``sparse/0``), else "arbitrary"."""
    if not poses:
        return "arbitrary"
    p = Path(poses)
    cands = [p] if p.is_file() else [p / "transforms.json", p.parent.parent / "transforms.json"]
    for c in cands:
        if c.suffix == ".json" and c.is_file():
            try:
                data = json.loads(c.read_text())
            except (OSError, ValueError):
                return "arbitrary"
            if isinstance(data, dict) and "photorecon_world" in data and data.get("units") in UNITS:
                return data["units"]
            return "arbitrary"
    return "arbitrary"


def _source_photos(model: SparseModel, folder: Path | None) -> list[Path | None]:
    """Each view's original photo in ``folder`` (same file name, else same stem), for its EXIF."""
    if folder is None or not folder.is_dir():
        return [None] * len(model.views)
    by_stem: dict[str, Path] = {}
    for f in sorted(folder.iterdir()):
        if f.is_file():
            by_stem.setdefault(f.stem, f)
    out = []
    for v in model.views:
        name = (v.image_file or v.name)
        out.append(folder / name if (folder / name).is_file() else by_stem.get(Path(name).stem, by_stem.get(v.name)))
    return out


def scale_output(out: str | Path, photos: str | Path | None, cfg: ScaleConfig | None = None,
                 base_units: str = "arbitrary") -> dict:
    """Metric scale for a poses output folder (``OUT/sparse/0``, ``OUT/images``, ``OUT/transforms.json``).

    ``photos``: the input photo folder (for EXIF GPS; None for a video). Markers are looked for in
    ``OUT/images`` (undistorted). Rewrites the model and transforms.json when a scale applies, and always
    records the units in transforms.json. Returns {"units": ..., "method": ..., "factor": the scale applied,
    "marker"/"gps": what was measured}; a marker
    or GPS that cannot be used logs a warning and leaves the units at ``base_units``."""
    from ..io.colmap_text import read_colmap_text, write_colmap_text

    cfg = cfg or ScaleConfig()
    if base_units not in UNITS:
        raise BadArgumentError(f"units: expected one of {UNITS}, got {base_units!r}")
    layout = Layout(out)
    if not layout.sparse.is_dir():
        raise InputDataError(f"{layout.sparse}: no model to scale")
    model = read_colmap_text(layout.sparse)
    info: dict = {"units": base_units, "method": "given" if base_units == "metre" else None, "factor": 1.0}
    scaled = None
    if cfg.marker_size is not None:
        res = marker_scale(model, {v.name: layout.images / (v.image_file or v.name + ".png")
                                   for v in model.views}, cfg.marker_size, cfg.marker_dict)
        info["marker"] = {"size_m": cfg.marker_size, "dictionary": cfg.marker_dict, **res.as_dict()}
        if res.scale is None:
            log.warning("metric scale: %s (units stay %s)", res.reason, base_units)
        else:
            if res.spread is not None and res.spread > 0.02:
                log.warning("metric scale: marker edges disagree by %.1f%% (std/mean); is a marker bent or "
                            "is --marker-size wrong?", 100 * res.spread)
            scaled = apply_similarity(model, res.scale)
            info.update(units="metre", method="markers", factor=res.scale)
            log.info("metric scale: %d markers, scale %.6g, edge spread %.2f%%", res.markers, res.scale,
                     100 * res.spread)
    elif cfg.gps and base_units != "metre":  # metric cameras given: their frame is kept
        sim = gps_alignment(model, _source_photos(model, Path(photos) if photos else None))
        if sim is not None:
            info["gps"] = sim.as_dict()
            scaled = apply_similarity(model, sim.s, sim.R, sim.t)
            info.update(units="metre", method="gps", factor=sim.s)
            log.info("metric scale: aligned to east-north-up metres with %d GPS photos (RMS %.2f m)",
                     sim.photos, sim.rms_m)
    if scaled is not None:
        write_colmap_text(scaled, layout.sparse)
        model = scaled
    _record_transforms(model, layout.transforms, info["units"])
    return info


def _record_transforms(model: SparseModel, path: Path, units: str) -> None:
    """Put the (scaled) cameras and ``units`` into the transforms.json that the poses step wrote, keeping its
    other keys (depth and mask paths, ...); rewrite it from the model when it does not match the views."""
    from ..conventions import nerf_from_opencv
    from ..io.atomic import atomic_write_json
    from ..io.nerf import write_transforms

    try:
        data = json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        data = None
    frames = data.get("frames") if isinstance(data, dict) else None
    by_file = {(v.image_file or v.name + ".png"): v for v in model.views}
    world = data.get("photorecon_world") if isinstance(data, dict) else None
    if (not isinstance(frames, list) or len(frames) != len(model.views) or world is None
            or any(not isinstance(f, dict) or Path(str(f.get("file_path", ""))).name not in by_file for f in frames)):
        write_transforms(model.views, path, world="none", units=units)
        return
    for f in frames:
        f["transform_matrix"] = nerf_from_opencv(by_file[Path(f["file_path"]).name].cam_from_world, world).tolist()
    data["units"] = units
    atomic_write_json(path, data)
