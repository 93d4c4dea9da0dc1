"""report.html: an interactive 3D view of OUT's mesh and cameras (``viewer``), with the textured model when the run
made one (``textured``) and its picture "photo | model" (``model_view``), the preview, the numbers, depth maps,
warnings and parameters, in one self-contained page."""
from __future__ import annotations

import base64
import html
import json
import logging
from pathlib import Path

from ..io.atomic import atomic_write_text
from ..layout import Layout
from .result import find_mesh, result_cameras
from .page import jpeg_tag
from .viewer import PAGE_MAX_FACES, VIEWER_CSS, viewer_html, viewer_payload

log = logging.getLogger("photorecon")


def _img_tag(path: Path, width: int | None = None) -> str:
    if not path.is_file():
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    w = f' width="{width}"' if width else ""
    return f'<img src="data:image/png;base64,{data}"{w} alt="{html.escape(path.name)}">'


def _model_payload(out: Path, texture: dict | None) -> dict | None:
    """What the 3D view embeds of OUT/model.glb (``textured.model_payload``), None without one."""
    from .textured import load_model, model_payload

    try:
        meshes = load_model(out, texture)
        return None if meshes is None else model_payload(meshes, PAGE_MAX_FACES)
    except Exception as exc:  # the mesh is still worth showing; say what went wrong
        log.warning("report.html: the textured model is not shown (%s)", exc)
        return None


def _model_view_section(out: Path, texture: dict | None) -> str:
    """OUT/model_view.png with its caption; empty without it."""
    path = Layout(out).model_view
    if not path.is_file():
        return ""
    view = (texture or {}).get("view") if isinstance(texture, dict) else None
    view = view if isinstance(view, dict) else {}
    photo = html.escape(str(view.get("photo", "an input photo")))
    diff = view.get("mean_abs_difference")
    caption = (f"Left: the photo {photo}; right: the textured model (model.glb) rendered from that photo's camera, "
               "white where the model does not reach. The photo is the one whose camera sees most of the model, one "
               "of those the model was textured from (not a held-out view)"
               + (f"; mean absolute difference where the model covers the picture: {diff:.1f} of 255"
                  if isinstance(diff, (int, float)) else "") + ".")
    return (f'<h2>Photo and model</h2><figure class="model-view">{jpeg_tag(path, path.name)}'
            f"<figcaption>{caption}</figcaption></figure>")


def _viewer_section(out: Path, texture: dict | None = None) -> str:
    """report.html's 3D view of OUT's mesh and cameras, and of OUT/model.glb when there is one (its frame:
    ``texture``, report.json's section); a line saying why when there is no mesh."""
    small = Layout(out).viewer_mesh
    path = small if small.is_file() else find_mesh(out)
    if path is None:
        return "<p>No mesh in this folder.</p>"
    from ..mesh import load_mesh

    try:
        mesh = load_mesh(path)
        cameras = result_cameras(out)
        return viewer_html(viewer_payload(mesh, cameras, model=_model_payload(out, texture)))
    except Exception as exc:  # the report's other contents still matter; say what went wrong
        log.warning("report.html: no 3D view (%s)", exc)
        return f"<p>No 3D view: {html.escape(str(exc))}</p>"


def write_html_report(out: Path, report: dict, extra_rows: dict | None = None) -> Path:
    """A self-contained OUT/report.html: an interactive 3D view of OUT's mesh and cameras, the preview, the
    numbers, depth maps, warnings, parameters. Images and mesh are embedded; it opens with no server."""
    from .page import REPORT_CSS, fact_rows, preview_html, sections_html, stage_rows, summary_facts

    texture = report.get("texture") if isinstance(report.get("texture"), dict) else None

    out = Path(out)
    facts = {**summary_facts(report), **(extra_rows or {})}
    depth_imgs = "".join(_img_tag(p, 240) for p in sorted((out / "depth").glob("*.png"))[:24]) if (out / "depth").is_dir() else ""
    warn = "".join(f"<li>{html.escape(w)}</li>" for w in report.get("warnings", [])) or "<li>none</li>"
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>photorecon report</title>
<meta name="viewport" content="width=device-width">
<style>{REPORT_CSS}
{VIEWER_CSS}</style>
</head><body><h1>photorecon report</h1>
<p>photorecon {html.escape(str(report.get('photorecon')))} &middot; input {html.escape(str(report.get('input')))}</p>
<h2>3D view</h2>{_viewer_section(out, texture)}
{_model_view_section(out, texture)}
<h2>Mesh</h2>{preview_html(out / 'preview.png')}
<h2>Summary</h2><table>{fact_rows(facts, report.get('units', 'arbitrary'))}</table>
<h2>Stages</h2><table>{stage_rows(report)}</table>
<h2>Depth maps</h2><div class="tiles depth">{depth_imgs}</div>
<h2>Warnings</h2><ul>{warn}</ul>
<h2>Facts by stage</h2>{sections_html(report)}
<h2>Parameters</h2><pre>{html.escape(json.dumps(report.get('parameters', {}), indent=1))}</pre>
</body></html>"""
    return atomic_write_text(out / "report.html", page)
