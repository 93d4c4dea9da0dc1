"""report.html: an interactive 3D view of OUT's mesh and cameras (``viewer``), the preview, the numbers, depth
maps, warnings and parameters, in one self-contained page."""
from __future__ import annotations

import base64
import html
import json
import logging
from pathlib import Path

from ..io.atomic import atomic_write_text
from ..layout import Layout
from .result import find_mesh, result_cameras
from .viewer import VIEWER_CSS, viewer_html, viewer_payload

log = logging.getLogger("photorecon")


def _img_tag(path: Path, width: int | None = None) -> str:
    if not path.is_file():
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    w = f' width="{width}"' if width else ""
    return f'<img src="data:image/png;base64,{data}"{w} alt="{html.escape(path.name)}">'


def _viewer_section(out: Path) -> str:
    """report.html's 3D view of OUT's mesh and cameras (a line saying why when there is none)."""
    small = Layout(out).viewer_mesh
    path = small if small.is_file() else find_mesh(out)
    if path is None:
        return "<p>No mesh in this folder.</p>"
    from ..mesh import load_mesh

    try:
        mesh = load_mesh(path)
        cameras = result_cameras(out)
        return viewer_html(viewer_payload(mesh, cameras))
    except Exception as exc:  # the report's other contents still matter; say what went wrong
        log.warning("report.html: no 3D view (%s)", exc)
        return f"<p>No 3D view: {html.escape(str(exc))}</p>"


def write_html_report(out: Path, report: dict, extra_rows: dict | None = None) -> Path:
    """A self-contained OUT/report.html: an interactive 3D view of OUT's mesh and cameras, the preview, the
    numbers, depth maps, warnings, parameters. Images and mesh are embedded; it opens with no server."""
    from .page import REPORT_CSS, fact_rows, preview_html, sections_html, stage_rows, summary_facts

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
<h2>3D view</h2>{_viewer_section(out)}
<h2>Mesh</h2>{preview_html(out / 'preview.png')}
<h2>Summary</h2><table>{fact_rows(facts, report.get('units', 'arbitrary'))}</table>
<h2>Stages</h2><table>{stage_rows(report)}</table>
<h2>Depth maps</h2><div class="tiles depth">{depth_imgs}</div>
<h2>Warnings</h2><ul>{warn}</ul>
<h2>Facts by stage</h2>{sections_html(report)}
<h2>Parameters</h2><pre>{html.escape(json.dumps(report.get('parameters', {}), indent=1))}</pre>
</body></html>"""
    return atomic_write_text(out / "report.html", page)
