"""Config checks: the values each config dataclass field accepts, declared once in its metadata and annotation,
and the one check of them that the configs run when they are built (``__post_init__`` calls ``check_config``) and that
the command line uses for its flags (``photorecon.cli.config`` builds each flag's parser from the same
declarations). A value out of range fails in the same terms from the Python API, a ``--config`` file, a preset
or the command line, before any work.

A field's annotation gives its type: ``int``, ``float``, ``bool``, ``str``, ``tuple[float, ...]``, ``X | None``
(``None`` allowed) or ``Literal[...]`` (one of the choices). Numeric fields declare their valid values in the
metadata::

    "range": (LO, HI)          inclusive bounds; None = unbounded on that side (always finite)
    "exclusive_min": True      LO itself is not allowed (a size or distance > 0)
    "also": (V, ...)           special values outside the range (``-1`` = all cores, ``0`` = off)
    "odd": True                an odd integer (a window size)
    "length": N                a comma-separated tuple of exactly N numbers (each within the range)
    "box": True                with length 6: xmin,ymin,zmin,xmax,ymax,zmax with each min below its max

A field only benchmarks change declares ``"tuning": True`` (the command line leaves it out of ``--help-all``).
A text field may declare ``"parse": FUNCTION`` (the check of its text: returns the value or raises
``argparse.ArgumentTypeError``), e.g. ``--cluster``'s address.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import numbers
import os
import types
import typing

from .errors import BadArgumentError

# --- ranges -------------------------------------------------------------------------------------------------


class Ranged:
    """An argparse ``type`` that parses a number (or a comma-separated tuple of numbers) and checks its range;
    its ``ArgumentTypeError`` states the valid values. ``kind`` is ``int`` or ``float``."""

    def __init__(self, kind: type, lo=None, hi=None, *, exclusive_min: bool = False, also: tuple = (),
                 odd: bool = False, length: int | None = None, sep: bool = False):
        self.kind, self.lo, self.hi = kind, lo, hi
        self.exclusive_min, self.also, self.odd = exclusive_min, tuple(also), odd
        self.length = length  # a tuple of exactly this many values
        self.sep = sep or length is not None  # comma-separated values (a list when length is None)
        self.__name__ = kind.__name__

    @classmethod
    def from_metadata(cls, kind: type, md: typing.Mapping) -> Ranged | None:
        if "range" not in md:
            return None
        lo, hi = md["range"]
        return cls(kind, lo, hi, exclusive_min=md.get("exclusive_min", False), also=md.get("also", ()),
                   odd=md.get("odd", False), length=md.get("length"))

    def describe(self) -> str:
        """'an integer in 64..65536 or 0', 'a number > 0', '6 values separated by commas, each a number'."""
        what = "an integer" if self.kind is int else "a number"
        lo, hi = _num(self.lo), _num(self.hi)
        if lo is not None and hi is not None and not self.exclusive_min:
            rng = f" in {lo}..{hi}"
        elif lo is not None and hi is not None:
            rng = f" > {lo} and <= {hi}"
        elif lo is not None:
            rng = f" {'>' if self.exclusive_min else '>='} {lo}"
        elif hi is not None:
            rng = f" <= {hi}"
        else:
            rng = "" if self.kind is int else " (finite)"
        text = what + rng + (", odd" if self.odd else "")
        if self.also:
            text += " or " + " or ".join(str(a) for a in self.also)
        if self.length is not None:
            return f"{self.length} values separated by commas, each {text}"
        if self.sep:
            return f"one or more values separated by commas, each {text}"
        return text

    def short(self) -> str:
        """The range for a help line: '64..65536 or 0', '> 0', '>= 1'."""
        lo, hi = _num(self.lo), _num(self.hi)
        if lo is not None and hi is not None:
            text = f"> {lo}, <= {hi}" if self.exclusive_min else f"{lo}..{hi}"
        elif lo is not None:
            text = f"{'>' if self.exclusive_min else '>='} {lo}"
        elif hi is not None:
            text = f"<= {hi}"
        else:
            text = "any"
        if self.odd:
            text += ", odd"
        if self.also:
            text += " or " + " or ".join(str(a) for a in self.also)
        return text

    def error(self, value) -> str | None:
        """Why ``value`` (already a number) is not valid, or None."""
        if _is_bool(value) or not isinstance(value, numbers.Real):
            return f"expected {self.describe()}, got {value!r}"
        if self.kind is int and not (isinstance(value, numbers.Integral)
                                     or (math.isfinite(value) and float(value).is_integer())):
            return f"expected {self.describe()}, got {value!r}"
        if not math.isfinite(value):
            return f"expected {self.describe()}, got {value!r}"
        if value in self.also:
            return None
        ok = ((self.lo is None or (value > self.lo if self.exclusive_min else value >= self.lo))
              and (self.hi is None or value <= self.hi) and (not self.odd or int(value) % 2 == 1))
        return None if ok else f"expected {self.describe()}, got {value!r}"

    def _one(self, text: str):
        text = text.strip()
        try:
            value = self.kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {text!r}") from None
        if self.error(value) is not None:
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {text!r}")
        return value

    def __call__(self, text: str):
        if not self.sep:
            return self._one(text)
        parts = [t for t in text.replace(",", " ").split()]
        if not parts or (self.length is not None and len(parts) != self.length):
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {text!r}")
        values = [self._one(t) for t in parts]
        return tuple(values) if self.length is not None else values

    def check(self, value) -> str | None:
        """Why a config value (a number, or a tuple/list of them) is not valid, or None."""
        if not self.sep:
            return self.error(value)
        if not isinstance(value, (tuple, list)) or (self.length is not None and len(value) != self.length):
            return f"expected {self.describe()}, got {value!r}"
        for v in value:
            if self.error(v) is not None:
                return f"expected {self.describe()}, got {value!r}"
        return None

    def __repr__(self) -> str:
        return f"Ranged({self.describe()})"


def _is_bool(value) -> bool:
    """True or False, also numpy's."""
    return isinstance(value, bool) or (type(value).__module__ == "numpy" and type(value).__name__ in ("bool_", "bool"))


def _num(x):
    """1000000.0 -> '1000000', 0.5 -> '0.5', None -> None (for messages)."""
    if x is None:
        return None
    if isinstance(x, float) and x.is_integer() and abs(x) < 1e9:
        return str(int(x))
    return f"{x:g}" if isinstance(x, float) else str(x)


def field_flag(f: dataclasses.Field) -> str:
    """A config field's plain flag: its name, ``--field-name`` (a ``metadata['flag']`` of another name is not
    read: a flag renamed to its field's name keeps its former name as an alias, ``photorecon.cli.config.RENAMED``)."""
    return "--" + f.name.replace("_", "-")


def field_kind(tp) -> tuple[type | None, bool]:
    """(int or float or None, is a tuple) of a field's annotation (``X | None`` unwrapped)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return field_kind(inner[0]) if len(inner) == 1 else (None, False)
    if origin is tuple:
        return float, True
    if tp in (int, float):
        return tp, False
    return None, False


def choices(tp) -> tuple | None:
    """The choices of a ``Literal[...]`` annotation (``X | None`` unwrapped), else None."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return choices(inner[0]) if len(inner) == 1 else None
    return tuple(args) if origin is typing.Literal else None


def _optional(tp) -> bool:
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp)


def _base(tp):
    """``X | None`` -> X."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        inner = [a for a in typing.get_args(tp) if a is not type(None)]
        return inner[0] if len(inner) == 1 else tp
    return tp


_HINTS: dict[type, dict] = {}


def _hints(cls) -> dict:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def field_error(f: dataclasses.Field, tp, value) -> str | None:
    """Why ``value`` is not valid for the config field ``f`` of annotation ``tp``, or None (see the module
    docstring for what a field declares)."""
    if value is None:
        return None if _optional(tp) or f.default is None else "expected a value, got None"
    options = choices(tp)
    if options is not None:
        return None if value in options else f"expected one of {', '.join(map(str, options))}, got {value!r}"
    base = _base(tp)
    if base is bool:
        return None if _is_bool(value) else f"expected true or false, got {value!r}"
    kind, is_tuple = field_kind(tp)
    if kind is not None:
        rng = Ranged.from_metadata(kind, f.metadata) or Ranged(kind)
        if is_tuple:
            rng.sep = True
        why = rng.check(value)
        if why is None and f.metadata.get("box") and not all(a < b for a, b in zip(value[:3], value[3:])):
            why = f"expected xmin < xmax, ymin < ymax, zmin < zmax, got {value!r}"
        return why
    if base is str:
        if not isinstance(value, (str, os.PathLike)):
            return f"expected text, got {type(value).__name__} {value!r}"
        parse = f.metadata.get("parse")
        if parse is not None:
            try:
                parse(os.fspath(value))
            except (argparse.ArgumentTypeError, ValueError) as exc:
                return str(exc)
    return None


def check_config(cfg) -> None:
    """Check every field of the config dataclass ``cfg`` against its declaration (type, ``Literal`` choices,
    range); raises ``BadArgumentError`` naming the field (and its command-line flag), the valid values and the
    value found. A config's ``__post_init__`` calls this, so a config is valid once built."""
    cls = type(cfg)
    hints = _hints(cls)
    for f in dataclasses.fields(cfg):
        why = field_error(f, hints[f.name], getattr(cfg, f.name))
        if why is not None:
            flag = "" if f.metadata.get("cli") is False else f" ({field_flag(f)})"
            raise BadArgumentError(f"{cls.__name__}.{f.name}{flag}: {why}")


def expect_config(value, cls, name: str):
    """``value`` when it is a ``cls`` (a config dataclass), ``cls()`` for None; else ``BadArgumentError``
    naming the argument ``name`` and the type expected."""
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise BadArgumentError(f"{name}: expected a {cls.__module__}.{cls.__name__} (build one with "
                               f"{cls.__name__}(...)), got {type(value).__name__} {_short(value)}")
    return value


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
