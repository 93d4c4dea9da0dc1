"""Command-line interface: thin. Parses arguments into the stage configs (dataclasses) and turns
``PhotoreconError`` into one clear line on stderr and the error class's exit code."""
from __future__ import annotations

import argparse
import logging
import sys

from . import __version__
from .config import COMMANDS
from .errors import PhotoreconError, from_os_error

log = logging.getLogger("photorecon")


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
    except OSError as exc:  # a file system failure that no stage turned into a photorecon error
        err = from_os_error(exc, getattr(args, "out", None))
        print(f"photorecon {args.command}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        print(f"photorecon {args.command}: interrupted; incomplete outputs were not kept", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
