"""Stage configs -> command-line flags, and the sub-command registry. The CLI is built from the configs
(dataclasses with a ``help`` per field and ``Literal`` choices), not from a parallel set of flags.

Every field of a stage config gets a **prefixed** flag, ``--PREFIX.NAME`` (``--mvs.max-size``,
``--fusion.trunc-voxels``; the prefix is the config's ``CLI_PREFIX`` or its class name without ``Config``), and
the plain alias ``--NAME`` as long as no other config on the same command already has that name. Two stages may
thus share a setting's name (``threads``, ``seed``): the plain flag belongs to the first config added, the
prefixed flags reach each stage on its own, and nothing crashes. Values land in ``args`` under the prefixed
``dest``, so ``config_from_args`` never mixes two stages' settings.
"""
from __future__ import annotations

import argparse
import dataclasses
import types
import typing

# --- configs -> argparse -----------------------------------------------------------------------------------


def config_prefix(config_cls) -> str:
    """``MVSConfig`` -> ``mvs``, ``FusionConfig`` -> ``fusion`` (or the class's ``CLI_PREFIX``)."""
    name = getattr(config_cls, "CLI_PREFIX", None) or config_cls.__name__.removesuffix("Config")
    return name.lower()


def _dest(prefix: str, name: str) -> str:
    return f"{prefix}.{name}"


def add_config_arguments(parser, config_cls, skip: tuple[str, ...] = (), defaults=None) -> None:
    """One ``--PREFIX.FLAG`` (and, when free, ``--FLAG``) per dataclass field of ``config_cls`` (or
    ``metadata['flag']``); help from ``field(metadata={'help': ...})``, choices from ``Literal`` annotations,
    ``--flag/--no-flag`` for booleans. Default values come from the instance ``defaults`` when given (a stage
    whose caller overrides a config default, e.g. the pipeline's wider TSDF truncation), else the class.
    ``parser`` may be an argument group: name clashes are checked across the whole parser."""
    hints = typing.get_type_hints(config_cls)
    prefix = config_prefix(config_cls)
    taken = parser._option_string_actions  # shared by a parser and its groups
    for f in dataclasses.fields(config_cls):
        if f.name in skip or f.metadata.get("cli") is False:
            continue
        plain = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
        prefixed = f"--{prefix}.{plain[2:]}"
        flags = [plain, prefixed] if plain not in taken else [prefixed]
        tp = hints[f.name]
        if defaults is not None:
            default = getattr(defaults, f.name)
        else:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        help_ = f.metadata.get("help", "")
        kw: dict = {"dest": _dest(prefix, f.name), "default": default, "help": f"{help_} (default: {default})"}
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp is bool:
            parser.add_argument(*flags, action=argparse.BooleanOptionalAction, **kw)
            continue
        if origin is typing.Literal:
            kw["choices"] = list(args)
            kw["type"] = type(args[0])
        elif origin in (typing.Union, types.UnionType):
            inner = [a for a in args if a is not type(None)]
            kw["type"] = _parse_tuple if typing.get_origin(inner[0]) is tuple else inner[0]
        elif origin is tuple:
            kw["type"] = _parse_tuple
        else:
            kw["type"] = tp
        kw["metavar"] = f.name.upper()
        parser.add_argument(*flags, **kw)


def _parse_tuple(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.replace(",", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None


def config_from_args(config_cls, args: argparse.Namespace, **overrides):
    """The config ``config_cls`` from the values ``add_config_arguments`` parsed into ``args`` (plus ``overrides``)."""
    prefix = config_prefix(config_cls)
    given = vars(args)
    values = {f.name: given[_dest(prefix, f.name)] for f in dataclasses.fields(config_cls)
              if _dest(prefix, f.name) in given}
    values.update(overrides)
    return config_cls(**values)


# --- commands ---------------------------------------------------------------------------------------------
COMMANDS: dict[str, typing.Callable[[argparse._SubParsersAction], None]] = {}


def command(fn):
    """Register a function ``fn(subparsers)`` that adds one sub-command."""
    COMMANDS[fn.__name__] = fn
    return fn
