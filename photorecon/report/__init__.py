"""Report: a result folder (mesh, cameras, depth maps, numbers) in, what people look at out.

- ``html``: report.html (previews, an interactive 3D view, depth maps, numbers, warnings, parameters), the
  standalone viewer page, and the local server of ``photorecon view``. The 3D viewer is ``viewer.js``, a
  package data file embedded into each page.
- ``page``: report.html's tables (the summary, the stages, every section of report.json) and its CSS (images
  and tables within the window's width; the preview's views wrap).
- ``numbers``: report.json's numbers written for reading: a unit where the number has one, 3 significant
  digits for measured values, counts with thousands separators (``format_length``, ``format_area``,
  ``format_seconds``, ``format_count``, ``format_percent``, ``format_value`` by a fact's key name).
- ``preview``: preview.png, the mesh rendered from a few viewpoints around it.
"""
from .html import (MESH_NAMES, VIEWER_CSS, VIEWER_ELEVATION_DEG, VIEWER_FOV_DEG, VIEWER_MAX_FACES,
                   VIEW_MAX_FACES, decimate_for_viewer, find_mesh, frustum_scale, frustum_segments,
                   initial_eye, initial_view, load_result, result_cameras, scene_up, start_viewer_server,
                   stop_viewer_server, viewer_html, viewer_payload, write_html_report, write_viewer_page,
                   _VIEWER_JS, _img_tag, _matte_glb, _thumbnail, _viewer_section)

__all__ = ["MESH_NAMES", "VIEWER_CSS", "VIEWER_ELEVATION_DEG", "VIEWER_FOV_DEG", "VIEWER_MAX_FACES",
           "VIEW_MAX_FACES", "decimate_for_viewer", "find_mesh", "frustum_scale", "frustum_segments",
           "initial_eye", "initial_view", "load_result", "result_cameras", "scene_up", "start_viewer_server",
           "stop_viewer_server", "viewer_html", "viewer_payload", "write_html_report", "write_viewer_page"]
