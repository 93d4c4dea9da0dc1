"""report.html's text parts and layout: the summary's facts, the stages' table, every section of report.json
(``poses``, ``depth``, ``mesh``, ``texture``, and any section a stage adds) with its numbers written for
reading (``numbers.format_value``: units, 3 significant digits, counts with thousands separators), the preview
cut into its tiles, and the page's CSS (images and tables fit the page's width at any window width).
report.json keeps the raw numbers."""
from __future__ import annotations

import base64
import html
from pathlib import Path

from .numbers import (NOT_AVAILABLE, format_area, format_count, format_length, format_megabytes, format_percent,
                      format_seconds, format_value, label, significant)

# report.json's top-level keys that are no stage's facts (shown elsewhere on the page or not at all)
NOT_FACTS = ("photorecon", "python", "versions", "input", "output", "parameters", "stages", "warnings", "units")

# the page's own CSS (the 3D viewer's is VIEWER_CSS): nothing is wider than the window; the preview's tiles
# and the depth maps wrap onto as many rows as the width needs and shrink when one alone is wider
REPORT_CSS = """*,*::before,*::after{box-sizing:border-box}
body{font-family:sans-serif;margin:2em;overflow-wrap:break-word}
img{max-width:100%;height:auto}
figure{margin:0 0 1em}
figcaption{font-size:90%;color:#444;max-width:60em}
.tiles{display:flex;flex-wrap:wrap;align-items:flex-start;gap:4px}
.tiles img{flex:0 1 auto;min-width:0;max-width:100%;height:auto}
table{border-collapse:collapse;max-width:100%}
td,th{border:1px solid #ccc;padding:4px 8px;overflow-wrap:anywhere;vertical-align:top;text-align:left}
td:first-child{overflow-wrap:normal}
td.num{text-align:right}
pre{white-space:pre-wrap;overflow-wrap:anywhere}
@media (max-width:600px){body{margin:.5em}td,th{padding:2px 4px}}"""


def summary_facts(report: dict) -> dict[str, str]:
    """The summary table's rows: label -> text, numbers with their units (report.json's ``units``)."""
    units = report.get("units", "arbitrary")
    poses, depth, mesh = (report.get(k) or {} for k in ("poses", "depth", "mesh"))
    closed = mesh.get("closed")
    facts = {"registered images": format_value("registered", poses.get("registered"), units),
             "unregistered": ", ".join(map(str, poses.get("unregistered") or [])) or "none",
             "depth maps": format_value("views", depth.get("views"), units),
             "depth source": format_value("source", depth.get("source"), units),
             "mesh vertices": format_value("vertices", mesh.get("vertices"), units),
             "mesh faces": format_value("faces", mesh.get("faces"), units),
             "watertight": format_value("watertight", mesh.get("watertight"), units),
             "boundary edges": format_value("boundary_edges", mesh.get("boundary_edges"), units),
             "open boundary length": format_length(mesh.get("boundary_length"), units),
             "area of filled holes": format_area(mesh.get("filled_area"), units),
             "closed companion": "none" if not isinstance(closed, dict) else
                 (f"{closed.get('file')}: {'watertight' if closed.get('watertight') else 'not watertight'}, "
                  f"filled area {format_area(closed.get('filled_area', 0), units)}"),
             "invented area (farther than invent_distance from every observed point)":
                 NOT_AVAILABLE if mesh.get("invented_fraction") is None else format_percent(mesh["invented_fraction"])}
    model = report.get("texture") or {}
    if isinstance(model.get("files"), dict) and model["files"]:  # the model stage's files: model.glb (+ obj)
        facts["textured model"] = (", ".join(f"{n} ({format_value('file_size', s, units)})"
                                             for n, s in model["files"].items())
                                   + f": {format_count(model.get('faces'))} faces, atlas "
                                   + ", ".join(f"{w}x{h}" for w, h in model.get("atlases") or []))
        if model.get("surface") == "closed":  # the closed surface: how much of it no photo saw
            share = model.get("invented_area_share")
            facts["textured model"] += "; closed surface" + ("" if model.get("watertight", True) else " (not watertight)")
            if share is not None:
                facts["textured model"] += (f", {format_percent(share)} of its area invented (no photo saw it: the "
                                            'part with the material "invented")')
        elif model.get("surface") == "open":
            facts["textured model"] += "; open surface"
        frame = model.get("frame")
        if isinstance(frame, dict) and frame.get("rule"):  # the model's upright frame: the rule, the units
            facts["textured model"] += f"; +Y up by the {frame['rule']}, in {frame.get('units', 'scene units')}"
    scene = mesh.get("scene")
    if isinstance(scene, dict):  # --scene: what was detected (or given) and why
        how = "detected" if scene.get("mode") == "auto" else "given"
        facts["scene (--scene auto|object|open)"] = (f"{scene.get('detected')} ({how}): {scene.get('reason')}; "
                                                    + ("support removed" if scene.get("support_removed")
                                                       else "nothing removed, the ground kept"))
    if "support_removed_faces" in mesh:  # an object capture: its support removed
        facts["support plane removed (n . X = c, and everything below the cut above it)"] = (
            f"n = {_vector(mesh.get('support_normal'))}, c = {format_length(mesh.get('support_offset'), units)}, "
            f"cut {format_length(mesh.get('support_cut'), units)}: {format_count(mesh.get('support_removed_faces'))} "
            f"faces, area {format_area(mesh.get('support_removed_area'), units)}")
    return facts


def _vector(v) -> str:
    """A direction (a list, or report.json's "x,y,z" text) as "(0.707, 0, 0.707)"."""
    if isinstance(v, str):
        try:
            v = [float(c) for c in v.split(",")]
        except ValueError:
            return v
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(significant(c) for c in v) + ")"
    return format_value("", v)


def fact_rows(facts: dict, units: str = "arbitrary") -> str:
    """Table rows of ``facts`` (label -> value: text as it is, a number by its label's kind)."""
    return "".join(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(format_value(str(k), v, units))}</td></tr>"
                   for k, v in facts.items())


def stage_rows(report: dict) -> str:
    """The stages table: its header and one row per stage (time, CPU time, peak memory, cached)."""
    rows = ["<tr><th>stage</th><th>time</th><th>CPU time</th><th>peak memory</th><th></th></tr>"]
    for stage, s in (report.get("stages") or {}).items():
        s = s if isinstance(s, dict) else {}
        cells = [format_seconds(s.get("seconds", 0)),
                 format_seconds(s["cpu_seconds"]) if s.get("cpu_seconds") is not None else "",
                 format_megabytes(s["peak_mb"]) if s.get("peak_mb") is not None else ""]
        rows.append(f"<tr><td>{html.escape(str(stage))}</td>"
                    + "".join(f'<td class="num">{html.escape(c)}</td>' for c in cells)
                    + f"<td>{'cached' if s.get('cached') else ''}</td></tr>")
    return "".join(rows)


def sections_html(report: dict) -> str:
    """Every stage section of report.json (a non-empty dict that ``NOT_FACTS`` does not name: ``poses``,
    ``depth``, ``mesh``, ``texture``, a section added later) as a titled table of its facts, for reading."""
    units = report.get("units", "arbitrary")
    parts = []
    for name, section in report.items():
        if name in NOT_FACTS or not isinstance(section, dict) or not section:
            continue
        rows = "".join(f"<tr><td>{html.escape(label(k))}</td><td>{html.escape(format_value(k, v, units))}</td></tr>"
                       for k, v in section.items())
        parts.append(f"<h3>{html.escape(label(name))}</h3><table>{rows}</table>")
    return "".join(parts) or "<p>none</p>"


def preview_tiles(path: Path) -> list[bytes]:
    """preview.png's views (``render_preview`` puts square tiles side by side), each a PNG, so the page can
    wrap them; the whole image when it is no row of squares; [] when there is no preview."""
    if not path.is_file():
        return []
    data = path.read_bytes()
    import cv2
    import numpy as np

    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim < 2:
        return [data]
    h, w = img.shape[:2]
    if h == 0 or w % h or w // h < 2:
        return [data]
    out = []
    for i in range(w // h):
        ok, png = cv2.imencode(".png", img[:, i * h:(i + 1) * h])
        if not ok:
            return [data]
        out.append(png.tobytes())
    return out


def png_tag(data: bytes, alt: str, width: int | None = None) -> str:
    w = f' width="{width}"' if width else ""
    return f'<img src="data:image/png;base64,{base64.b64encode(data).decode()}"{w} alt="{html.escape(alt)}">'


def jpeg_tag(path: Path, alt: str, quality: int = 90) -> str:
    """An image file embedded as JPEG (a photo-like PNG of 1.6 MB is 0.26 MB at quality 90); empty if unreadable."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality]) if img is not None else (False, None)
    if not ok:
        return ""
    return f'<img src="data:image/jpeg;base64,{base64.b64encode(data.tobytes()).decode()}" alt="{html.escape(alt)}">'


def preview_html(path: Path) -> str:
    """The preview's views in a row that wraps (``tiles preview``); empty without a preview."""
    tiles = preview_tiles(path)
    if not tiles:
        return ""
    alts = [path.name] if len(tiles) == 1 else [f"{path.name}, view {i + 1}" for i in range(len(tiles))]
    return '<div class="tiles preview">' + "".join(png_tag(t, a) for t, a in zip(tiles, alts)) + "</div>"
