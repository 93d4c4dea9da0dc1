"""Numbers as people read them (report.html, printed summaries): a unit where the number has one and a sensible
precision. report.json keeps the raw numbers; these functions only write them for reading.

- measured values (lengths, areas, durations, ratios, memory) to 3 significant digits: ``format_length``,
  ``format_area``, ``format_seconds``, ``format_percent``, ``format_megabytes``, ``format_bytes``,
  ``format_number``;
- counts as integers with thousands separators: ``format_count``;
- ``format_value(key, value, units)``: any fact of report.json written by its key's name (``UNIT_OF_KEY`` for
  whole names, ``UNIT_OF_SUFFIX`` for endings such as ``_seconds``, ``_area``, ``_fraction``; ``A_per_B`` as A
  "per B"), so a new section's facts read the same way without code of their own.

``units`` is report.json's ``units``: "metres" when the scene's scale is known (lengths in m, or mm under
1 m; areas in m², or mm² under 0.01 m²), anything else ("arbitrary") means scene units ("units",
"units²"). None and NaN read "n/a"; infinities "∞".
"""
from __future__ import annotations

import math
from numbers import Integral, Real

SIGNIFICANT = 3  # digits of a measured value
NOT_AVAILABLE = "n/a"
METRIC = ("metres", "meters", "metre", "meter", "m")


def _bad(x) -> str | None:
    """The text of a value that is no finite number (None and NaN: "n/a"; an infinity: "∞" or "-∞"; anything
    else that is no number, a boolean included: its own text), else None."""
    if x is None:
        return NOT_AVAILABLE
    if isinstance(x, bool) or not isinstance(x, Real):
        return str(x)
    x = float(x)
    if math.isnan(x):
        return NOT_AVAILABLE
    if math.isinf(x):
        return "∞" if x > 0 else "-∞"
    return None


def _infinite(bad: str) -> bool:
    return bad in ("∞", "-∞")


def significant(x: float, digits: int = SIGNIFICANT) -> str:
    """``x`` rounded to ``digits`` significant digits, written plainly with thousands separators and no
    trailing zeros after the decimal point (506.417 -> "506", 5064.17 -> "5,060", 0.0907798 -> "0.0908",
    2.5 -> "2.5"); in e-notation below 1e-4 or from 1e15 on ("1.23e+20", "1e-09")."""
    bad = _bad(x)
    if bad is not None:
        return bad
    x = float(x)
    if x == 0:
        return "0"
    r = float(f"{x:.{digits - 1}e}")  # rounded to `digits` significant digits (9.996 -> 10.0)
    if not 1e-4 <= abs(r) < 1e15:
        mantissa, _, exponent = f"{r:.{digits - 1}e}".partition("e")
        return f"{mantissa.rstrip('0').rstrip('.')}e{exponent}"
    decimals = max(digits - 1 - math.floor(math.log10(abs(r))), 0)
    text = f"{r:,.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def format_number(x, digits: int = SIGNIFICANT) -> str:
    """A measured number without a unit, to ``digits`` significant digits."""
    return significant(x, digits)


def is_metric(units: str | None) -> bool:
    return str(units or "").strip().lower() in METRIC


def format_length(x, units: str | None = "arbitrary") -> str:
    """A length: "1.23 m", "506 mm" (metric under 1 m) or "506 units" (scene units)."""
    bad = _bad(x)
    if bad is not None:
        return f"{bad} {'m' if is_metric(units) else 'units'}" if _infinite(bad) else bad
    x = float(x)
    if not is_metric(units):
        return f"{significant(x)} units"
    if x != 0 and abs(float(significant(abs(x)).replace(",", ""))) < 1:
        return f"{significant(x * 1e3)} mm"
    return f"{significant(x)} m"


def format_area(x, units: str | None = "arbitrary") -> str:
    """An area: "2.5 m²", "5,000 mm²" (metric under 0.01 m²) or "9.08 units²" (scene units)."""
    bad = _bad(x)
    if bad is not None:
        return f"{bad} {'m²' if is_metric(units) else 'units²'}" if _infinite(bad) else bad
    x = float(x)
    if not is_metric(units):
        return f"{significant(x)} units²"
    if x != 0 and abs(float(significant(abs(x)).replace(",", ""))) < 1e-2:
        return f"{significant(x * 1e6)} mm²"
    return f"{significant(x)} m²"


def format_seconds(x) -> str:
    """A duration: "12.3 s" under a minute ("< 0.001 s" under a millisecond), "4 min 5 s" under an hour, then
    "2 h 3 min" ("1,230 h" from 1,000 hours on)."""
    bad = _bad(x)
    if bad is not None:
        return f"{bad} s" if _infinite(bad) else bad
    x = float(x)
    if x < 0:
        return "-" + format_seconds(-x)
    if 0 < x < 1e-3:
        return "< 0.001 s"
    if float(significant(x).replace(",", "")) < 60:
        return f"{significant(x)} s"
    s = int(round(x))
    if s < 3600:
        return f"{s // 60} min {s % 60} s" if s % 60 else f"{s // 60} min"
    if x >= 1000 * 3600:
        return f"{significant(x / 3600)} h"
    m = int(round(x / 60))
    return f"{m // 60:,} h {m % 60} min" if m % 60 else f"{m // 60:,} h"


def format_count(n) -> str:
    """A count: an integer with thousands separators ("1,234,567"); a float is rounded to one."""
    bad = _bad(n)
    if bad is not None:
        return bad
    return f"{int(round(n)):,}"


def format_percent(fraction) -> str:
    """A ratio (0.123 = 12.3%) as a percentage to 3 significant digits."""
    bad = _bad(fraction)
    if bad is not None:
        return f"{bad}%" if _infinite(bad) else bad
    return f"{significant(100 * float(fraction))}%"


def format_megabytes(mb) -> str:
    """Memory given in MB (2^20 bytes): "840 MB", "1.5 GB" from 1,024 MB on."""
    bad = _bad(mb)
    if bad is not None:
        return f"{bad} MB" if _infinite(bad) else bad
    mb = float(mb)
    if abs(float(significant(mb).replace(",", ""))) >= 1024:
        return f"{significant(mb / 1024)} GB"
    return f"{significant(mb)} MB"


def format_bytes(n) -> str:
    """A size in bytes: "512 B", "12.3 kB", "4.5 MB", "1.2 GB" (powers of 1,024, as the log lines' MB)."""
    bad = _bad(n)
    if bad is not None:
        return f"{bad} B" if _infinite(bad) else bad
    n = float(n)
    if abs(float(significant(n).replace(",", ""))) < 1024:
        return f"{significant(n)} B"
    if abs(float(significant(n / 1024).replace(",", ""))) < 1024:
        return f"{significant(n / 1024)} kB"
    return format_megabytes(n / 2 ** 20)


def _with(suffix: str):
    def fmt(x, units=None):
        bad = _bad(x)
        return f"{significant(x)}{suffix}" if bad is None else f"{bad}{suffix}" if _infinite(bad) else bad
    return fmt


# how each kind of fact is written: kind -> (value, units) -> text
KINDS = {
    "length": format_length,
    "area": format_area,
    "seconds": lambda x, units=None: format_seconds(x),
    "percent": lambda x, units=None: format_percent(x),
    "percent_points": _with("%"),  # already a percentage (e.g. 12.3 for 12.3%)
    "megabytes": lambda x, units=None: format_megabytes(x),
    "bytes": lambda x, units=None: format_bytes(x),
    "degrees": _with("°"),
    "pixels": lambda x, units=None: format_count(x) + (" px" if _bad(x) is None else ""),
    "count": lambda x, units=None: format_count(x),
}
# whole key names of report.json's facts whose unit their name's ending does not tell
UNIT_OF_KEY = {
    "seconds": "seconds", "voxel_size": "length", "invent_distance": "length", "support_offset": "length",
    "support_cut": "length", "area": "area", "filled_area": "area", "atlas_size": "pixels", "max_size": "pixels",
    "peak_mb": "megabytes", "file_size": "bytes", "bytes": "bytes", "valid_fraction": "percent", "fraction": "percent", "ratio": "percent",
    "length": "length", "distance": "length", "radius": "length", "diagonal": "length", "spacing": "length",
}
# key endings, tried in order after UNIT_OF_KEY
UNIT_OF_SUFFIX = (
    ("_seconds", "seconds"), ("_secs", "seconds"),
    ("_length", "length"), ("_distance", "length"), ("_radius", "length"), ("_diagonal", "length"),
    ("_spacing", "length"), ("_area", "area"), ("_fraction", "percent"), ("_ratio", "percent"),
    ("_pct", "percent_points"), ("_percent", "percent_points"),
    ("_mb", "megabytes"), ("_bytes", "bytes"), ("_deg", "degrees"), ("_degrees", "degrees"), ("_px", "pixels"), ("_pixels", "pixels"),
    ("_count", "count"), ("_faces", "count"), ("_vertices", "count"), ("_views", "count"),
    ("_edges", "count"), ("_points", "count"),
)


def kind_of(key: str) -> str | None:
    """The kind of number (a key of ``KINDS``) report.json's fact ``key`` holds, by its name; None: unknown."""
    k = str(key).strip().lower()
    if k in UNIT_OF_KEY:
        return UNIT_OF_KEY[k]
    for suffix, kind in UNIT_OF_SUFFIX:
        if k.endswith(suffix) and len(k) > len(suffix):
            return kind
    return None


def format_value(key: str, value, units: str | None = "arbitrary", max_items: int = 8,
                 kind: str | None = None) -> str:
    """``value`` (a fact of report.json named ``key``) for reading: numbers by their key's kind (``kind_of``,
    else ``kind``, the kind of the section holding it, e.g. the stages of ``sfm_seconds``; none: an int as a
    count, a float to 3 significant digits), ``A_per_B`` as A "per B", booleans "yes"/"no", None "n/a", lists
    and dicts item by item (at most ``max_items``, then how many more), text as it is unless it is a
    comma-separated list of numbers ("0,0.70710678,0.70710678" -> "(0, 0.707, 0.707)")."""
    key = str(key)
    kind = kind_of(key) or kind
    if value is None:
        return NOT_AVAILABLE
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, str):
        numbers = _numbers_in(value)
        return value if numbers is None else format_value(key, numbers, units, max_items, kind)
    if isinstance(value, dict):
        items = list(value.items())
        text = "; ".join(f"{label(k)}: {format_value(k, v, units, max_items, kind)}" for k, v in items[:max_items])
        return (text + (f"; … {len(items) - max_items} more" if len(items) > max_items else "")) or "none"
    if isinstance(value, (list, tuple)):
        text = ", ".join(format_value(key, v, units, max_items, kind) for v in value[:max_items])
        more = f", … {len(value) - max_items} more" if len(value) > max_items else ""
        if not value:
            return "none"
        numeric = all(isinstance(v, Real) and not isinstance(v, bool) for v in value)
        return f"({text}{more})" if numeric else text + more
    if not isinstance(value, Real):
        return str(value)
    head, sep, per = key.rpartition("_per_")
    if sep and head and per:
        return f"{format_value(head, value, units, max_items, kind)} per {label(per)}"
    if kind is not None:
        return KINDS[kind](value, units)
    if isinstance(value, Integral):
        return format_count(value)
    return significant(value)


def _numbers_in(text: str) -> list[float] | None:
    """The numbers of a comma-separated list of decimals written as text (report.json's
    "0.00000,0.70711,0.70711" of a direction), else None."""
    parts = text.split(",")
    if len(parts) < 2 or not all("." in p for p in parts):  # "1,234": a number with a thousands separator
        return None
    try:
        return [float(p) for p in parts]
    except ValueError:
        return None


def label(key) -> str:
    """A fact's key for reading: underscores as spaces ("boundary_length" -> "boundary length")."""
    return str(key).replace("_", " ")
