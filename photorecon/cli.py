"""Command-line interface: thin. Parses arguments into the stage configs (dataclasses) and turns
``PhotoreconError`` into one clear line on stderr and the error class's exit code."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import typing

from . import __version__
from .errors import PhotoreconError

log = logging.getLogger("photorecon")


# --- configs -> argparse -----------------------------------------------------------------------------------
def add_config_arguments(parser: argparse.ArgumentParser, config_cls, skip: tuple[str, ...] = (),
                         defaults=None) -> None:
    """One ``--flag`` per dataclass field of ``config_cls`` (or ``metadata['flag']``); help from ``field(metadata={'help': ...})``,
    choices from ``Literal`` annotations, ``--flag/--no-flag`` for booleans. Default values come from the
    instance ``defaults`` when given (a stage whose caller overrides a config default), else the class."""
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        if f.name in skip or f.metadata.get("cli") is False:
            continue
        flag = f.metadata.get("flag") or "--" + f.name.replace("_", "-")
        tp = hints[f.name]
        if defaults is not None:
            default = getattr(defaults, f.name)
        else:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        help_ = f.metadata.get("help", "")
        kw: dict = {"dest": f.name, "default": default, "help": f"{help_} (default: {default})"}
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, **kw)
            continue
        if origin is typing.Literal:
            kw["choices"] = list(args)
            kw["type"] = type(args[0])
        elif origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
            inner = [a for a in args if a is not type(None)]
            kw["type"] = _parse_tuple if typing.get_origin(inner[0]) is tuple else inner[0]
        elif origin is tuple:
            kw["type"] = _parse_tuple
        else:
            kw["type"] = tp
        parser.add_argument(flag, **kw)


def _parse_tuple(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.replace(",", " ").split())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers separated by commas, got {text!r}") from None


def config_from_args(config_cls, args: argparse.Namespace, **overrides):
    names = {f.name for f in dataclasses.fields(config_cls)}
    values = {k: v for k, v in vars(args).items() if k in names}
    values.update(overrides)
    return config_cls(**values)


# --- commands ---------------------------------------------------------------------------------------------
COMMANDS: dict[str, typing.Callable[[argparse._SubParsersAction], None]] = {}


def command(fn):
    """Register a function ``fn(subparsers)`` that adds one sub-command."""
    COMMANDS[fn.__name__] = fn
    return fn


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="photorecon",
        description="Photos -> camera poses, per-image depth and one fused triangle mesh, on a plain CPU.")
    parser.add_argument("--version", action="version", version=f"photorecon {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors; no progress bars")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _load_commands()
    for add in COMMANDS.values():
        add(sub)
    for sp in sub.choices.values():  # -q / -v also after the sub-command
        sp.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="only errors; no progress bars")
        sp.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help="debug messages")
    return parser


def _load_commands() -> None:
    """Import the modules that define sub-commands (each registers itself with ``@command``)."""
    from . import commands  # noqa: F401


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR if args.quiet else logging.DEBUG if args.verbose else logging.INFO,
                        format="%(message)s")
    from . import progress

    progress.set_enabled(not args.quiet)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except PhotoreconError as exc:
        print(f"photorecon {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"photorecon {args.command}: interrupted; incomplete outputs were not kept", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
