"""report.html's numbers and layout: each number with its unit and 3 significant digits (report/numbers.py),
report.json's raw numbers untouched, and a page whose images fit the window's width (its CSS, and in headless
Chromium when it is installed: nothing wider than the window at phone to desktop widths, the preview's views
wrapping)."""
from __future__ import annotations

import copy
import json
import math
import re
import time
from html.parser import HTMLParser

import cv2
import numpy as np
import pytest
import trimesh

from photorecon.report import write_html_report
from photorecon.report.numbers import (format_area, format_bytes, format_count, format_length, format_megabytes, format_percent,
                                       format_seconds, format_value, kind_of, significant)
from photorecon.report.page import REPORT_CSS, preview_tiles

NAN, INF = float("nan"), float("inf")


# --- the formatting functions --------------------------------------------------------------------------------
@pytest.mark.parametrize("x, text", [
    (506.417375857237, "506"), (9.077979734659586, "9.08"), (5064.17, "5,060"), (123456.7, "123,000"),
    (0.0907798, "0.0908"), (2.5, "2.5"), (10, "10"), (9.996, "10"), (0.99951, "1"), (-3.14159, "-3.14"),
    (0, "0"), (-0.0, "0"), (1e20, "1e+20"), (-1.23456e20, "-1.23e+20"), (1.5e-9, "1.5e-09"), (0.00012345, "0.000123"),
    (NAN, "n/a"), (None, "n/a"), (INF, "∞"), (-INF, "-∞"), (np.float32(0.5), "0.5"), (np.int64(1234), "1,230"),
])
def test_significant_rounds_to_three_digits(x, text):
    assert significant(x) == text


@pytest.mark.parametrize("x, units, text", [
    (506.417375857237, "arbitrary", "506 units"), (506.417375857237, "metres", "506 m"),
    (0.5064, "metres", "506 mm"), (0.0015, "metres", "1.5 mm"), (1.0, "metres", "1 m"),
    (0.99996, "metres", "1 m"),  # 1,000 mm once rounded: metres
    (0.015122662772822891, "metres", "15.1 mm"), (0.015122662772822891, "arbitrary", "0.0151 units"),
    (-0.4, "metres", "-400 mm"), (-2.25, "metres", "-2.25 m"), (0, "metres", "0 m"), (0, "arbitrary", "0 units"),
    (12345.678, "metres", "12,300 m"), (NAN, "metres", "n/a"), (None, "metres", "n/a"), (INF, "metres", "∞ m"),
    (3.0, None, "3 units"), (3.0, "meters", "3 m"),
])
def test_format_length(x, units, text):
    assert format_length(x, units) == text


@pytest.mark.parametrize("x, units, text", [
    (9.077979734659586, "arbitrary", "9.08 units²"), (9.077979734659586, "metres", "9.08 m²"),
    (0.0123, "metres", "0.0123 m²"), (0.005, "metres", "5,000 mm²"), (2.5e-7, "metres", "0.25 mm²"),
    (0, "metres", "0 m²"), (-1.5, "arbitrary", "-1.5 units²"), (NAN, "arbitrary", "n/a"), (-INF, "metres", "-∞ m²"),
])
def test_format_area(x, units, text):
    assert format_area(x, units) == text


@pytest.mark.parametrize("x, text", [
    (12.3456, "12.3 s"), (0.361234, "0.361 s"), (0, "0 s"), (3.99e-6, "< 0.001 s"), (59.4, "59.4 s"),
    (59.97, "1 min"), (94.038, "1 min 34 s"), (245.2, "4 min 5 s"), (3599.6, "1 h"), (7380.0, "2 h 3 min"),
    (90061.0, "25 h 1 min"), (1e10, "2,780,000 h"), (-12.34, "-12.3 s"), (NAN, "n/a"), (None, "n/a"), (INF, "∞ s"),
])
def test_format_seconds(x, text):
    assert format_seconds(x) == text


@pytest.mark.parametrize("x, text", [
    (1234567, "1,234,567"), (0, "0"), (-4421, "-4,421"), (12.6, "13"), (np.int64(290975), "290,975"),
    (10 ** 18, "1,000,000,000,000,000,000"), (NAN, "n/a"), (None, "n/a"), (INF, "∞"),
])
def test_format_count(x, text):
    assert format_count(x) == text


@pytest.mark.parametrize("x, text", [
    (0.54723, "54.7%"), (0.00028, "0.028%"), (1.0, "100%"), (0, "0%"), (-0.125, "-12.5%"), (12.3456, "1,230%"),
    (NAN, "n/a"), (INF, "∞%"),
])
def test_format_percent(x, text):
    assert format_percent(x) == text


@pytest.mark.parametrize("x, text", [
    (839.7, "840 MB"), (1005.1, "1,010 MB"), (1074.7, "1.05 GB"), (0.5, "0.5 MB"), (2 ** 20, "1,020 GB"),
    (NAN, "n/a"),
])
def test_format_megabytes(x, text):
    assert format_megabytes(x) == text


@pytest.mark.parametrize("x, text", [
    (512, "512 B"), (0, "0 B"), (12_345, "12.1 kB"), (1023.9, "1,020 B"), (1536, "1.5 kB"), (4_718_592, "4.5 MB"), (3 * 2 ** 30, "3 GB"),
    (NAN, "n/a"), (None, "n/a"),
])
def test_format_bytes(x, text):
    assert format_bytes(x) == text


def test_format_value_writes_a_fact_by_its_key():
    """A fact reads by its key's name, so a section added to report.json needs no code of its own."""
    m = "metres"
    assert format_value("boundary_length", 54.34255150846353, m) == "54.3 m"
    assert format_value("filled_area", 0.9860724800725916, "arbitrary") == "0.986 units²"
    assert format_value("voxel_size", 0.015122662772822891, m) == "15.1 mm"
    assert format_value("invented_fraction", 0.00028) == "0.028%"
    assert format_value("seconds_per_view", 7.464237004749823) == "7.46 s per view"
    assert format_value("triangulation_seconds", 3.99e-6) == "< 0.001 s"
    assert format_value("peak_mb", 923.14) == "923 MB"
    assert format_value("atlas_size", 4096) == "4,096 px"
    assert format_value("file_size", 4_718_592) == "4.5 MB" and format_value("cache_bytes", 2048) == "2 kB"
    assert format_value("rot_mean_deg", 0.489812) == "0.49°"
    assert format_value("faces", 290975) == "290,975"  # an int of an unknown kind: a count
    assert format_value("fscore", 0.964612) == "0.965"  # a float of an unknown kind: 3 digits, no unit
    assert format_value("watertight", False) == "no" and format_value("streamed", True) == "yes"
    assert format_value("closed", None) == "n/a" and format_value("unregistered", []) == "none"
    assert format_value("mesher", "tsdf") == "tsdf"
    assert format_value("support_normal", [0.0, 0.7071067811865476, 0.7071067811865476]) == "(0, 0.707, 0.707)"
    assert format_value("support_normal", "0.00000,0.70710678,-0.70710678") == "(0, 0.707, -0.707)"
    assert format_value("faces", "1,234") == "1,234" and format_value("x", "1,234.5") == "1,234.5"
    # a section's kind passes to its items: the SfM steps of sfm_seconds are durations
    assert format_value("sfm_seconds", {"extraction": 2.154, "mapping_upsampled": 61.98}) == \
        "extraction: 2.15 s; mapping upsampled: 1 min 2 s"
    fill = format_value("fill", {"fill_radius": 0.15122662772822892, "filled_faces": 26324}, m)
    assert fill == "fill radius: 151 mm; filled faces: 26,324"
    assert format_value("resolution", {f"v{i}": "full" for i in range(10)}, max_items=3) == \
        "v0: full; v1: full; v2: full; … 7 more"
    # a section another stage adds later: by the same names
    assert format_value("model", {"surface_area": 12.3456789, "coverage_fraction": 0.87654321,
                                  "bake_seconds": 245.2, "texel_size_px": 2048}, m) == \
        "surface area: 12.3 m²; coverage fraction: 87.7%; bake seconds: 4 min 5 s; texel size px: 2,048 px"


def test_kind_of_names():
    assert [kind_of(k) for k in ("seconds", "cpu_seconds", "boundary_length", "filled_area", "support_cut",
                                 "confirmed_fraction", "peak_mb", "faces", "mesher", "views_s")] == \
        ["seconds", "seconds", "length", "area", "length", "percent", "megabytes", None, None, None]


# --- report.html ---------------------------------------------------------------------------------------------
class _Text(HTMLParser):
    """The page's visible text, without scripts, styles and the parameters' raw JSON (<pre>)."""

    def __init__(self):
        super().__init__()
        self.parts, self.skip = [], 0

    def handle_starttag(self, tag, attrs):
        self.skip += tag in ("script", "style", "pre")

    def handle_endtag(self, tag):
        self.skip -= tag in ("script", "style", "pre")

    def handle_data(self, data):
        if not self.skip:
            self.parts.append(data)


def visible_text(page: str) -> str:
    p = _Text()
    p.feed(page)
    return " ".join(p.parts)


NUMBER = re.compile(r"(?<![\w.])\d[\d,]*(?:\.\d+)?(?:e[+-]?\d+)?")


def significant_digits(token: str) -> int:
    """How many significant digits a written number carries ("506" 3, "0.0908" 3, "5,060" 3, "1.5e-09" 2)."""
    mantissa = token.replace(",", "").split("e")[0]
    digits = mantissa.replace(".", "").lstrip("0")
    if "." not in mantissa:
        digits = digits.rstrip("0")
    return len(digits)


LONG = {  # report.json as reconstruct writes it, numbers at full float precision
    "photorecon": "0.1.0", "input": "/photos", "units": "arbitrary",
    "stages": {"poses": {"seconds": 19.265123456, "peak_mb": 839.7123, "cpu_seconds": 19.23456789},
               "depth": {"seconds": 94.0381234, "peak_mb": 923.1, "cpu_seconds": 88.1198765},
               "fusion": {"seconds": 0.0, "cached": True}},
    "poses": {"source": "sfm", "registered": 12, "unregistered": [],
              "sfm_seconds": {"extraction": 2.15412345, "mapping": 1.27912345},
              "scale": {"units": "arbitrary", "method": None, "factor": 1.0}},
    "depth": {"source": "mvs", "views": 12, "seconds_per_view": 7.464237004749823,
              "triangulation_seconds": 3.9930000639287755e-06, "confirmed_fraction": 0.54723123},
    "mesh": {"vertices": 147595, "faces": 290975, "voxel_size": 0.015122662772822891, "watertight": False,
             "boundary_edges": 4421, "invented_fraction": 0.000281234, "invent_distance": 0.030245325545645782,
             "boundary_length": 506.417375857237, "filled_area": 9.077979734659586,
             "fill": {"fill_radius": 0.15122662772822892, "holes": 686},
             "closed": {"file": "mesh_closed.ply", "watertight": True, "filled_area": 1.23456789123},
             "support_normal": "0.00012,0.70710678,0.70710678", "support_offset": -0.412345678,
             "support_cut": 0.0451234567, "support_removed_faces": 1234, "support_removed_area": 2.5123456789},
    "model": {"surface_area": 12.3456789012, "coverage_fraction": 0.876543219876, "texel_size_px": 2048,
              "bake_seconds": 245.23456789},
    "warnings": [], "parameters": {"fusion": {"voxel_size": 0.0123456789}},
}
COUNTS = {"147,595", "290,975", "4,421", "1,234", "2,048"}  # the counts: integers, every digit kept


def test_report_html_numbers_have_units_and_three_digits(tmp_path):
    """No number on the page carries more than 4 significant digits (counts aside), the measured ones carry
    their units, and report.json's dict is left as it was."""
    report = copy.deepcopy(LONG)
    text = visible_text(write_html_report(tmp_path, report).read_text(encoding="utf-8"))
    assert report == LONG  # the raw numbers stay for report.json
    tokens = NUMBER.findall(text)
    assert len(tokens) > 40
    too_precise = [t for t in tokens if t not in COUNTS and significant_digits(t) > 4]
    assert not too_precise, too_precise
    for raw in ("506.417", "9.07797", "0.015122", "19.265", "7.4642"):
        assert raw not in text
    for shown in ("open boundary length 506 units", "area of filled holes 9.08 units²",
                  "mesh_closed.ply: watertight, filled area 1.23 units²", "mesh faces 290,975",
                  "(farther than invent_distance from every observed point) 0.0281%",
                  "n = (0.00012, 0.707, 0.707), c = -0.412 units, cut 0.0451 units: 1,234 faces, area 2.51 units²",
                  "poses 19.3 s 19.2 s 840 MB", "depth 1 min 34 s 1 min 28 s 923 MB", "fusion 0 s cached",
                  "seconds per view 7.46 s per view", "confirmed fraction 54.7%", "voxel size 0.0151 units",
                  "sfm seconds extraction: 2.15 s; mapping: 1.28 s",
                  # a section only a later stage writes, by its keys' names
                  "surface area 12.3 units²", "coverage fraction 87.7%", "bake seconds 4 min 5 s",
                  "texel size px 2,048 px"):
        assert shown in " ".join(text.split()), shown


def test_report_html_lengths_in_metres_when_the_scale_is_known(tmp_path):
    report = {**copy.deepcopy(LONG), "units": "metres"}
    report["poses"]["scale"] = {"units": "metres", "method": "gps", "factor": 0.0123456789}
    text = " ".join(visible_text(write_html_report(tmp_path, report).read_text(encoding="utf-8")).split())
    assert "open boundary length 506 m " in text and "area of filled holes 9.08 m²" in text
    assert "voxel size 15.1 mm" in text and "c = -412 mm, cut 45.1 mm" in text
    assert "surface area 12.3 m²" in text and "scale units: metres; method: gps; factor: 0.0123" in text
    assert "units" not in text.replace("scale units: metres", "")


def test_report_json_keeps_the_raw_numbers(tmp_path):
    """The pipeline writes report.json from the same dict before report.html: formatting changes neither."""
    from photorecon.io.atomic import atomic_write_json

    report = copy.deepcopy(LONG)
    atomic_write_json(tmp_path / "report.json", report)
    write_html_report(tmp_path, report)
    back = json.loads((tmp_path / "report.json").read_text())
    assert back["mesh"]["boundary_length"] == 506.417375857237
    assert back["stages"]["poses"]["seconds"] == 19.265123456


# --- the page's width -----------------------------------------------------------------------------------------
def _css_rules(css: str) -> dict[str, str]:
    css = re.sub(r"@media[^{]*\{((?:[^{}]*\{[^}]*\})*)\s*\}", "", css)  # the rules at any width
    return {sel.strip(): body for sels, body in re.findall(r"([^{}]+)\{([^}]*)\}", css) for sel in sels.split(",")}


def test_page_css_keeps_images_within_the_width():
    rules = _css_rules(REPORT_CSS)
    assert "max-width:100%" in rules["img"] and "height:auto" in rules["img"]
    assert "flex-wrap:wrap" in rules[".tiles"]
    assert "max-width:100%" in rules[".tiles img"] and "min-width:0" in rules[".tiles img"]
    assert "max-width:100%" in rules["table"] and "pre-wrap" in rules["pre"]


def _tiles(tmp_path, n=4, size=120):
    colours = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255)]
    img = np.concatenate([np.full((size, size, 3), colours[i % 5], np.uint8) for i in range(n)], axis=1)
    cv2.imwrite(str(tmp_path / "preview.png"), img)
    return tmp_path / "preview.png"


def test_preview_is_cut_into_its_views(tmp_path):
    """preview.png (render_preview's square views side by side) goes into the page as one image per view, in
    order, so the row can wrap; an image that is no row of squares stays whole."""
    tiles = preview_tiles(_tiles(tmp_path))
    assert len(tiles) == 4
    imgs = [cv2.imdecode(np.frombuffer(t, np.uint8), cv2.IMREAD_COLOR) for t in tiles]
    assert all(i.shape == (120, 120, 3) for i in imgs)
    assert [tuple(int(c) for c in i[60, 60]) for i in imgs] == [(255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0)]
    cv2.imwrite(str(tmp_path / "odd.png"), np.zeros((30, 40, 3), np.uint8))
    assert preview_tiles(tmp_path / "odd.png") == [(tmp_path / "odd.png").read_bytes()]
    assert preview_tiles(tmp_path / "none.png") == []
    page = write_html_report(tmp_path, {"mesh": {"faces": 1}}).read_text()
    assert page.count('alt="preview.png, view ') == 4 and '<div class="tiles preview">' in page


@pytest.mark.browser
def test_report_fits_the_window_in_a_browser(tmp_path):
    """In headless Chromium at phone, laptop and wide widths nothing on report.html is wider than the window
    (no sideways scrolling); the preview's four 360-pixel views stand in one row on a wide window and one per
    row on a phone, each shrunk to the width there with its aspect kept."""
    from test_viewer import Browser

    from photorecon.mesh import export

    export(trimesh.creation.icosphere(2), tmp_path / "mesh.ply")
    _tiles(tmp_path, 4, 360)
    (tmp_path / "depth").mkdir()
    for i in range(6):
        cv2.imwrite(str(tmp_path / "depth" / f"v{i}.png"), np.full((300, 400, 3), 90, np.uint8))
    report = {**copy.deepcopy(LONG), "input": "/photos/" + "a" * 300,
              "poses": {**LONG["poses"], "unregistered": ["b" * 200 + ".jpg"]}}
    page = write_html_report(tmp_path, report)
    probe = ("JSON.stringify({scroll: document.documentElement.scrollWidth, width: innerWidth, "
             "wide: Array.from(document.querySelectorAll('body *')).filter(e => e.getBoundingClientRect().right > "
             "innerWidth + 0.5).map(e => e.tagName + '.' + e.className), "
             "tiles: Array.from(document.querySelectorAll('.tiles.preview img')).map(i => {"
             "const r = i.getBoundingClientRect(); return [r.left, r.top, r.width, r.height]}), "
             "ready: document.readyState})")
    b = Browser(tmp_path / "profile", 1700, 900)
    try:
        b.open(page.as_uri())
        seen = {}
        for width in (1700, 800, 320):
            b.call("Emulation.setDeviceMetricsOverride", width=width, height=900, deviceScaleFactor=1, mobile=False)
            for _ in range(50):
                got = json.loads(b.eval(probe) or "{}")
                if got.get("ready") == "complete" and got["width"] == width and len(got["tiles"]) == 4:
                    break
                time.sleep(0.2)
            seen[width] = got
    finally:
        b.close()
    for width, got in seen.items():
        assert got["width"] == width and got["scroll"] <= width and not got["wide"], (width, got)
        assert all(math.isclose(w, h, abs_tol=1) for _, _, w, h in got["tiles"]), (width, got["tiles"])
    wide = seen[1700]["tiles"]
    assert len({round(t) for _, t, _, _ in wide}) == 1 and all(math.isclose(w, 360, abs_tol=1) for _, _, w, _ in wide)
    phone = seen[320]["tiles"]
    assert len({round(t) for _, t, _, _ in phone}) == 4 and all(w < 320 for _, _, w, _ in phone)
