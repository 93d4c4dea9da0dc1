"""Presets and settings files: ``apply_preset`` fills in a preset's values (``--quality``) that the user left open;
``apply_settings_file`` reads a ``--config FILE.toml`` into the parsed arguments, each key checked like its flag
(``photorecon.cli.config`` builds the flags; a flag's former name works as a key too, with a pointer to the new
one)."""
from __future__ import annotations

import argparse
import typing

from .config import Ranged, _parse_tuple, _Renamed, _RenamedToValue, force, given


def apply_preset(args: argparse.Namespace, values: typing.Mapping[str, object]) -> list[str]:
    """Set each ``dest -> value`` of a preset that the user did not give (on the command line or in a settings
    file); dests the command does not have are skipped. Returns the dests set."""
    done = []
    user = given(args)
    for dest, value in values.items():
        if dest in user or not hasattr(args, dest):
            continue
        setattr(args, dest, value)
        done.append(dest)
    return done


def _file_value(action: argparse.Action, value, where: str):
    """A settings file's ``value`` for ``action``, parsed and checked like the same text on the command line."""
    from ..errors import BadArgumentError

    if isinstance(action, (argparse.BooleanOptionalAction, argparse._StoreTrueAction, argparse._StoreFalseAction)):
        if not isinstance(value, bool):
            raise BadArgumentError(f"{where}: expected true or false, got {value!r}")
        return value if not isinstance(action, argparse._StoreFalseAction) else not value
    if isinstance(value, (dict, bool)) or (isinstance(value, list) and not getattr(action.type, "sep", False)
                                           and action.type is not _parse_tuple and action.nargs is None):
        raise BadArgumentError(f"{where}: expected a {'number' if isinstance(action.type, Ranged) else 'value'}, "
                               f"got {value!r}")
    text = ",".join(str(v) for v in value) if isinstance(value, list) else str(value)
    try:
        parsed = action.type(text) if callable(action.type) else text
    except (argparse.ArgumentTypeError, ValueError, TypeError) as exc:
        raise BadArgumentError(f"{where}: {exc}") from None
    if action.choices is not None and parsed not in action.choices:
        raise BadArgumentError(f"{where}: expected one of {', '.join(map(str, action.choices))}, got {value!r}")
    return parsed


def apply_settings_file(parser: argparse.ArgumentParser, args: argparse.Namespace, path) -> list[str]:
    """Read a TOML settings file into ``args``: top-level keys are plain flag names (``quality = "preview"``,
    ``max_size = 800``), a table per stage prefix holds that stage's settings (``[mvs]`` ``max_size = 800``,
    ``[fusion]`` ``voxel_size = 0.002``). Flags given on the command line win. Every key is checked like its
    flag; an unknown key is an error. Returns the dests set."""
    import logging
    import tomllib
    from pathlib import Path

    from ..errors import BadArgumentError, InputDataError

    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputDataError(f"--config {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputDataError(f"--config {path}: cannot read it ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise BadArgumentError(f"--config {path}: not valid TOML ({exc})") from None
    items = []
    for key, value in data.items():
        if isinstance(value, dict):
            items += [(f"--{key}.{k.replace('_', '-')}", f"[{key}] {k}", v) for k, v in value.items()]
        else:
            items.append((f"--{key.replace('_', '-')}", key, value))
    user = given(args)
    done = []
    for option, name, value in items:
        action = parser._option_string_actions.get(option)
        unknown = action is None or action.dest in (argparse.SUPPRESS, "help") or option in ("--config", "--help-all")
        if unknown or (isinstance(action, _RenamedToValue) and option.startswith("--no-")):
            raise BadArgumentError(f"--config {path}: {name}: no such setting for '{parser.prog}' "
                                   f"(see {parser.prog} --help-all)")
        if isinstance(action, _RenamedToValue):  # object = true: scene = "object", as the boolean did
            if not isinstance(value, bool):
                raise BadArgumentError(f"--config {path}: {name}: expected true or false, got {value!r}")
            field = action.dest.split(".", 1)[1]
            key = f"[{action.dest.split('.')[0]}] {field}" if "." in option else field
            if value:
                force(args, action.dest, action.value)
                logging.getLogger("photorecon").warning('--config %s: %s = true is now %s = "%s" (the former name '
                                                        "still works, for now)", path, name, key, action.value)
                done.append(action.dest)
            else:
                logging.getLogger("photorecon").warning("--config %s: %s = false is the default now and changes "
                                                        "nothing (the setting is %s)", path, name, key)
            continue
        parsed = _file_value(action, value, f"--config {path}: {name}")
        if isinstance(action, _Renamed):
            new = action.new_prefixed if "." in option else action.new_plain
            key = f"[{new[2:].split('.')[0]}] {new.split('.', 1)[1]}" if "." in new else new[2:]
            logging.getLogger("photorecon").warning("--config %s: %s is now %s (the former name still works, for "
                                                    "now)", path, name, key.replace("-", "_"))
        if action.dest in user:
            continue  # the command line wins
        setattr(args, action.dest, parsed)
        done.append(action.dest)
    if done:
        setattr(args, "_given", user | set(done))  # a preset does not override the file either
    return done
