"""Command-line interface: thin. Parses arguments into the stage configs (dataclasses) and turns every failure
into one line on stderr and an exit code: a ``PhotoreconError`` its class's code, a parse error or an
out-of-range value 2, a failed allocation ``OutOfMemoryError``'s 11, anything unexpected ``InternalError``'s 10 (``-v`` shows the traceback), Ctrl-C 130 and
SIGTERM 143 (both leave no incomplete output behind, and a re-run resumes); stdout closed by its reader 141."""
from __future__ import annotations

import argparse
import logging
import re
import signal
import sys
import warnings

from .. import __version__
from .config import COMMANDS, Parser
from .settings import apply_settings_file
from ..errors import InternalError, PhotoreconError, from_os_error, is_out_of_memory, out_of_memory

log = logging.getLogger("photorecon")

EXIT_INTERRUPTED = 130  # SIGINT (Ctrl-C): 128 + 2
EXIT_TERMINATED = 143  # SIGTERM: 128 + 15
STAGE_COMMANDS = ("reconstruct", "sfm", "mvs", "depth", "fuse", "texture", "demo")  # pycolmap, Open3D, numba
EXIT_BROKEN_PIPE = 141  # stdout's reader went away (photorecon eval ... | head): 128 + SIGPIPE, as the shell's own


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM: every ``except KeyboardInterrupt`` / ``except BaseException``
    clean-up runs as for Ctrl-C (partial folders removed, the output lock released)."""


def build_parser() -> Parser:
    parser = Parser(
        prog="photorecon",
        description="Photos -> camera poses, per-image depth and one fused triangle mesh, on a plain CPU.")
    parser.add_argument("--version", action="version", version=f"photorecon {__version__}")
    parser.add_argument("-q", "--quiet", action="store_true", help="only errors; no progress bars")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug messages; tracebacks of unexpected errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    _load_commands()
    for add in COMMANDS.values():
        add(sub)
    for sp in sub.choices.values():  # -q / -v also after the sub-command
        sp.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS, help="only errors; no progress bars")
        sp.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                        help="debug messages; tracebacks of unexpected errors")
        if any("." in o for a in sp._actions for o in a.option_strings):  # a command built from stage configs
            sp.add_argument("--config", metavar="FILE.toml",
                            help="settings file: [STAGE] tables (e.g. [mvs] max_size = 800) or plain flag names; "
                                 "flags on the command line win")
        if isinstance(sp, Parser):
            sp.add_help_all()
    return parser


def _load_commands() -> None:
    """Import the modules that define sub-commands (each registers itself with ``@command``)."""
    from . import commands  # noqa: F401


def _one_line(text: str, limit: int = 400) -> str:
    """``text`` on one line, at most ``limit`` characters: each line break (with the spaces around it) becomes
    one space; other spaces stay, since a file name in the message may hold two in a row."""
    text = re.sub(r"[ \t]*[\r\n]+[ \t]*", " ", str(text)).strip()
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _on_sigterm(signum, frame):
    raise Terminated()


def _install_signal_handlers(native: bool = True) -> dict:
    """SIGTERM -> ``Terminated`` (clean up as for Ctrl-C); SIGINT -> ``KeyboardInterrupt``. With ``native``, first
    load the native libraries that install handlers of their own: pycolmap's glog puts a failure handler (a
    native stack dump) on SIGTERM when it is imported; ours replaces it. Returns the previous handlers."""
    if native:
        try:
            import pycolmap  # noqa: F401
        except (ImportError, RuntimeError, OSError):  # not installed, or no address space left to load it: the
            pass  # command that needs it says so
    old = {}
    try:
        old[signal.SIGTERM] = signal.signal(signal.SIGTERM, _on_sigterm)
        old[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
    except ValueError:  # not the main thread (main() called from a thread): keep what is there
        pass
    return old


def _restore_signal_handlers(old: dict) -> None:
    for sig, handler in old.items():
        try:
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
        except (ValueError, TypeError):  # pragma: no cover
            pass


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv``; returns the exit code. A parse error, an out-of-range value or ``--help``
    raises ``SystemExit`` (argparse's; code 2 or 0) before any work."""
    old_handlers = _install_signal_handlers(native=False)  # a SIGTERM while the parser is built: the same line
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:  # before the command started
        print("photorecon: interrupted", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED
    finally:
        _restore_signal_handlers(old_handlers)


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.ERROR if args.quiet else logging.DEBUG if args.verbose else logging.INFO,
                        format="%(message)s")
    for name in ("PIL", "matplotlib", "numba", "asyncio", "fsspec"):  # their debug logs are not photorecon's
        logging.getLogger(name).setLevel(max(logging.INFO, logging.getLogger().level))
    from .. import progress

    progress.set_enabled(not args.quiet)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    prog = f"photorecon {args.command}"
    try:
        if getattr(args, "config", None):
            apply_settings_file(parser.command_parser(args.command), args, args.config)
        from ..resources import fit_address_space

        # under ulimit -v: fewer malloc arenas; the commands that run the stages load the libraries (or exit 11) first
        fit_address_space(preload=args.command in STAGE_COMMANDS)
        _install_signal_handlers()  # again, after the native libraries' own
        with warnings.catch_warnings():
            if not args.verbose:  # libraries' own Python warnings (deprecations, numpy's RuntimeWarning, ...): not
                warnings.simplefilter("ignore")  # photorecon's to report, nothing a user can act on; -v shows them
            return int(args.func(args) or 0)
    except PhotoreconError as exc:
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # the reader of stdout closed it: nothing left to say to it, nor an error
        import os

        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit's flush
        except (OSError, ValueError):
            pass
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # a file system failure that no stage turned into a photorecon error
        err = from_os_error(exc, getattr(args, "out", None))
        print(f"{prog}: error: {_one_line(err)}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt as exc:
        print(f"{prog}: interrupted; incomplete outputs were not kept", file=sys.stderr)
        return EXIT_TERMINATED if isinstance(exc, Terminated) else EXIT_INTERRUPTED
    except Exception as exc:  # a bug: one line, the traceback with -v
        if args.verbose:
            import traceback

            traceback.print_exc()
        if is_out_of_memory(exc):  # outside a stage (which names itself)
            err = out_of_memory(args.command)
            print(f"{prog}: error: {_one_line(err)}", file=sys.stderr)
            return err.exit_code
        print(f"{prog}: error: {type(exc).__name__}: {_one_line(exc, 300)} (run with -v for details)", file=sys.stderr)
        return InternalError.exit_code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
