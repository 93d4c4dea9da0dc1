"""Report: a result folder (mesh, cameras, depth maps, numbers) in, what people look at out.

- ``html``: report.html (previews, an interactive 3D view, depth maps, numbers, warnings, parameters).
- ``viewer``: the 3D view embedded in report.html and in the standalone viewer page (``--html``): the mesh's
  data, its first view, the cameras' frusta; the viewer itself is ``viewer.js``, a package data file embedded
  into each page.
- ``live``: the local server of ``photorecon view`` (viser), open only to the viewer's own page.
- ``result``: a result folder or mesh file read for viewing (mesh, cameras, photos), also while a run writes it.
- ``page``: report.html's tables (the summary, the stages, every section of report.json) and its CSS (images
  and tables within the window's width; the preview's views wrap).
- ``numbers``: report.json's numbers written for reading: a unit where the number has one, 3 significant
  digits for measured values, counts with thousands separators (``format_length``, ``format_area``,
  ``format_seconds``, ``format_count``, ``format_percent``, ``format_value`` by a fact's key name).
- ``preview``: preview.png, the mesh rendered from a few viewpoints around it.
- ``textured``: the textured model (model.glb) read back into the cameras' frame, and what report.html's 3D view
  embeds of it (its atlas downscaled to ``PAGE_ATLAS_SIDE``).
- ``model_view``: model_view.png, the photo that sees most of the model beside the model rendered from its camera.

Two mesh budgets: ``PAGE_MAX_FACES`` for a page (report.html, ``--html``: the mesh travels inside the file) and
``LIVE_MAX_FACES`` for ``photorecon view``'s live viewer (over a local websocket).
"""
from .html import write_html_report
from .live import LIVE_MAX_FACES, start_viewer_server, stop_viewer_server
from .model_view import model_view_output
from .result import MESH_NAMES, find_mesh, load_result, result_cameras
from .textured import PAGE_ATLAS_SIDE
from .viewer import (PAGE_MAX_FACES, VIEWER_CSS, VIEWER_ELEVATION_DEG, VIEWER_FOV_DEG, decimate_for_viewer,
                     frustum_scale, frustum_segments, initial_eye, initial_view, scene_up, viewer_html,
                     viewer_payload, write_viewer_page)

__all__ = ["LIVE_MAX_FACES", "MESH_NAMES", "PAGE_ATLAS_SIDE", "PAGE_MAX_FACES", "VIEWER_CSS", "VIEWER_ELEVATION_DEG",
           "VIEWER_FOV_DEG", "decimate_for_viewer", "find_mesh", "frustum_scale", "frustum_segments", "initial_eye",
           "initial_view", "load_result", "model_view_output", "result_cameras", "scene_up", "start_viewer_server",
           "stop_viewer_server", "viewer_html", "viewer_payload", "write_html_report", "write_viewer_page"]
