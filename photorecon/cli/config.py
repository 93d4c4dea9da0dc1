"""Stage configs -> command-line flags, and the sub-command registry. The CLI is built from the configs
(dataclasses with a ``help`` per field and ``Literal`` choices), not from a parallel set of flags.

Every field of a stage config gets a **prefixed** flag, ``--PREFIX.NAME`` (``--mvs.max-size``,
``--fusion.trunc-voxels``; the prefix is the config's ``CLI_PREFIX`` or its class name without ``Config``), and
the plain alias ``--NAME`` as long as no other config on the same command already has that name. Two stages may
thus share a setting's name (``threads``, ``seed``): the plain flag belongs to the first config added, the
prefixed flags reach each stage on its own, and nothing crashes. Values land in ``args`` under the prefixed
``dest``, so ``config_from_args`` never mixes two stages' settings.

Each field declares its valid values once (``photorecon.config_checks``: a range in its metadata, ``Literal`` choices,
a ``parse`` check for text): the flag's parser checks them when the arguments are parsed (a bad value exits 2
with one line naming the flag and the valid values, before any work), and the config checks them again when it
is built (values from a ``--config`` file, a preset, or the Python API), with the same ``Ranged`` objects.

Settings are resolved in this order, each overriding the one before: the config's default, the command's own
default (``defaults=``), a preset (``--quality``), a ``--config FILE.toml``, and flags given on the command line.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import types
import typing

# ranges, choices and the check of a config's fields: photorecon.config_checks (the configs check themselves with it)
from ..config_checks import Ranged, check_config as validate, field_flag, field_kind  # noqa: F401  (validate: API)


# --- the command-line parser ----------------------------------------------------------------------------------


class _Given:
    """Mixin for argparse actions: record the ``dest`` of every option the user gave in ``namespace._given``,
    so that presets and settings files fill in only what the command line left open."""

    def __call__(self, parser, namespace, values, option_string=None):
        super().__call__(parser, namespace, values, option_string)  # type: ignore[misc]
        _kept(namespace, "_given", set).add(self.dest)


def _kept(namespace: argparse.Namespace, name: str, make):
    """The collection ``namespace.<name>`` that the actions add to, made by ``make`` on first use."""
    return vars(namespace).setdefault(name, make())


class _Store(_Given, argparse._StoreAction):
    pass


class _StoreTrue(_Given, argparse._StoreTrueAction):
    pass


class _StoreFalse(_Given, argparse._StoreFalseAction):
    pass


class _StoreConst(_Given, argparse._StoreConstAction):
    pass


class BooleanFlag(_Given, argparse.BooleanOptionalAction):
    """``--flag/--no-flag``, recorded as given."""


class _RenamedToValue(argparse.Action):
    """A former boolean flag that is now one value of another setting (``RENAMED_TO_VALUE``): ``--FLAG`` sets
    that value, ``--no-FLAG`` changes nothing; either records ``(old, new, dest)`` in ``namespace._renamed`` for
    ``config_from_args``'s one-line pointer. The value is kept in ``namespace._forced`` too: it wins over the
    setting's own flag wherever that stands on the command line, as the boolean did."""

    value = new_plain = new_prefixed = ""

    def __init__(self, option_strings, dest, default=None, help=None):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        new = self.new_prefixed if option_string and "." in option_string else self.new_plain
        if option_string and option_string.startswith("--no-"):
            new = None  # the default: nothing to set
        else:
            force(namespace, self.dest, self.value)
        _kept(namespace, "_renamed", list).append((option_string, new, self.dest))


def force(namespace: argparse.Namespace, dest: str, value) -> None:
    """Set ``dest`` to ``value`` whatever else the command line or a settings file says (a former boolean flag,
    ``_RenamedToValue``), and record it as given."""
    setattr(namespace, dest, value)
    _kept(namespace, "_forced", dict)[dest] = value
    _kept(namespace, "_given", set).add(dest)


class _Renamed(_Store):
    """A flag's former name: stores like the flag and records ``(old, new, dest)`` in ``namespace._renamed`` so that
    ``config_from_args`` says, once and in one line, what it is called now."""

    new_plain = new_prefixed = ""

    def __call__(self, parser, namespace, values, option_string=None):
        super().__call__(parser, namespace, values, option_string)
        new = self.new_prefixed if option_string and "." in option_string else self.new_plain
        _kept(namespace, "_renamed", list).append((option_string, new, self.dest))


def given(args: argparse.Namespace) -> set[str]:
    """The ``dest`` of every option given on the command line (or by a ``--config`` file)."""
    return getattr(args, "_given", None) or set()


class _HelpAll(argparse.Action):
    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        parser.print_help(full=True)
        parser.exit()


class _Formatter(argparse.HelpFormatter):
    """In a short help (``short = True``): an option's plain flags only, not its ``--PREFIX.NAME`` aliases."""

    short = False

    def _format_action_invocation(self, action):
        if self.short and action.option_strings:
            plain = [o for o in action.option_strings if "." not in o]
            if plain and len(plain) < len(action.option_strings):
                action = argparse.Action(plain, action.dest, nargs=action.nargs, metavar=action.metavar,
                                         choices=action.choices)
        return super()._format_action_invocation(action)


class Parser(argparse.ArgumentParser):
    """``ArgumentParser`` with one-line errors (``PROG: error: MESSAGE``, exit 2, no usage block), a short ``-h``
    (only the options in ``common``; the rest are listed by ``--help-all``) and option tracking (``given``)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)
        super().__init__(*args, **kwargs)
        self.common: set[str] | None = None  # option strings -h shows; None = all
        self.short_help: dict[str, str] = {}  # option -> its help text in -h (default: the full one)
        self._short = False
        for name, cls in ((None, _Store), ("store", _Store), ("store_true", _StoreTrue),
                          ("store_false", _StoreFalse), ("store_const", _StoreConst)):
            self.register("action", name, cls)

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_args(self, args=None, namespace=None):  # type: ignore[override]
        ns, extra = self.parse_known_args(args, namespace)
        if extra:  # said by the sub-command's parser, which names the command
            sub = self.command_parser(getattr(ns, "command", None))
            where = sub or self
            where.error(f"unrecognized arguments: {' '.join(extra)} (see {where.prog} --help"
                        + (" or --help-all)" if isinstance(where, Parser) and where.common is not None else ")"))
        return ns

    def command_parser(self, name: str | None) -> argparse.ArgumentParser | None:
        """The parser of sub-command ``name`` (None when there is no such sub-command)."""
        for a in self._actions:
            if isinstance(a, argparse._SubParsersAction) and name in a.choices:
                return a.choices[name]
        return None

    def set_common(self, options: typing.Iterable[str], short_help: typing.Mapping[str, str] | None = None) -> None:
        """Show only these options (and the positionals) in ``-h``, with the help texts ``short_help`` where
        given; add ``--help-all`` for the full list. Options the parser does not have are ignored (a field
        another stage may add later)."""
        self.common = set(options) | {"-h", "--help-all"}
        self.short_help = dict(short_help or {})
        self.add_help_all()

    def _get_formatter(self):
        formatter = super()._get_formatter()
        formatter.short = getattr(self, "_short", False)
        return formatter

    def add_help_all(self) -> None:
        if "--help-all" not in self._option_string_actions:
            self.add_argument("--help-all", action=_HelpAll, help="list every option, grouped by stage, and exit")

    def hidden_actions(self) -> list[argparse.Action]:
        """The options ``-h`` leaves out."""
        if self.common is None:
            return []
        return [a for a in self._actions if a.option_strings and a.help is not argparse.SUPPRESS
                and not set(a.option_strings) & self.common]

    def _short_usage(self) -> str:
        """'%(prog)s [-h] [--help-all] [OPTIONS] -o OUT IMAGES': the required options and the positionals."""
        parts = ["%(prog)s [-h] [--help-all] [OPTIONS]"]
        for a in self._actions:
            if a.option_strings and a.required:
                parts.append(f"{a.option_strings[0]} {a.metavar or a.dest.upper()}")
        for a in self._actions:
            if not a.option_strings and a.help is not argparse.SUPPRESS:
                parts.append(a.metavar or a.dest.upper())
        return " ".join(parts)

    def format_help(self, full: bool = False) -> str:  # type: ignore[override]
        tuning = sum(1 for a in self._actions if getattr(a, "tuning_help", None))
        note = (f"\n{tuning} tuning settings, which only benchmarks change, are not listed here; docs/cli.md lists them "
                "(Tuning settings)\n" if tuning else "")
        hidden = self.hidden_actions()
        if not hidden:
            return super().format_help() + note
        saved_usage = self.usage
        self.usage = self._short_usage()
        saved = [(a, a.help) for a in self._actions]
        self._short = not full
        if not full:
            for a in self._actions:
                if a in hidden:
                    a.help = argparse.SUPPRESS
                elif set(a.option_strings) & set(self.short_help):
                    a.help = self.short_help[next(o for o in a.option_strings if o in self.short_help)]
        try:
            text = super().format_help()
        finally:
            self.usage = saved_usage
            self._short = False
            for a, h in saved:
                a.help = h
        if not full:
            text += f"\n{len(hidden)} more options, every stage's settings: {self.prog} --help-all\n"
        return text + (note if full else "")

    def print_help(self, file=None, full: bool = False):  # type: ignore[override]
        import sys

        (file or sys.stdout).write(self.format_help(full=full))


# A field's flag is its name. Flags renamed to their field's name, by config prefix: former name -> field. The
# former flag (plain and prefixed) and the former --config key still work, hidden, with a one-line pointer to the
# new name; docs/cli.md lists them.
RENAMED: dict[str, dict[str, str]] = {
    "mvs": {"mvs": "method"},  # --mvs NAME: --method NAME (--mvs.method)
    "fusion": {"fusion_memory": "memory_gb"},  # --fusion-memory GB: --memory-gb GB (--fusion.memory-gb)
    # reconstruct --texture-faces N, --atlas-size N: --model-faces N, --max-atlas N (the model's texturing)
    "model": {"texture_faces": "model_faces", "atlas_size": "max_atlas"},
}

# Boolean flags that became one value of another setting, by config prefix: former flag -> (field, value). The
# former flag (plain and prefixed, and its --config key) still works, hidden, with a one-line pointer: ``--object``
# is ``--scene object`` and, as before, wins over a --scene given too; ``--no-object`` (the default) changes nothing.
RENAMED_TO_VALUE: dict[str, dict[str, tuple[str, str]]] = {
    "clean": {"object": ("scene", "object")},  # --object: --scene object
}

def is_tuning(prefix: str, f: dataclasses.Field) -> bool:
    """``f`` is a tuning setting: one only benchmarks change (their defaults were measured; docs/benchmarks.md),
    marked in its config with ``metadata={"tuning": True}``. Not listed by --help-all; docs/cli.md lists them
    under "Tuning settings"; a flag or a --config key sets them as any other."""
    return bool(f.metadata.get("tuning"))


def add_config_arguments(parser, config_cls, skip: tuple[str, ...] = (), defaults=None) -> None:
    """One ``--PREFIX.NAME`` (and, when free, ``--NAME``) per dataclass field ``NAME`` of ``config_cls``; help
    from ``field(metadata={'help': ...})``, choices from ``Literal`` annotations, ``--flag/--no-flag`` for
    booleans, ranges from the metadata (module docstring), a text setting's check from ``metadata['parse']``
    (argparse's ``type``); tuning settings hidden, former names as aliases (``_finish``). Default values come from
    the instance ``defaults`` when given (a stage whose caller overrides a config default, e.g. the pipeline's
    wider TSDF truncation), else the class. ``parser`` may be an argument group: name clashes are checked
    across the whole parser."""
    hints = typing.get_type_hints(config_cls)
    prefix = config_prefix(config_cls)
    taken = parser._option_string_actions  # shared by a parser and its groups
    for f in dataclasses.fields(config_cls):
        if f.name in skip or f.metadata.get("cli") is False:
            continue
        plain = field_flag(f)
        prefixed = f"--{prefix}.{plain[2:]}"
        flags = [plain, prefixed] if plain not in taken else [prefixed]
        tp = hints[f.name]
        if defaults is not None:
            default = getattr(defaults, f.name)
        else:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc]
        help_ = f.metadata.get("help", "")
        kw: dict = {"dest": _dest(prefix, f.name), "default": default}
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp is bool:
            kw["help"] = f"{help_} (default: {'on' if default else 'off'})"
            _finish(parser, parser.add_argument(*flags, action=BooleanFlag, **kw), prefix, f)
            continue
        kind, is_tuple = field_kind(tp)
        rng = Ranged.from_metadata(kind, f.metadata) if kind is not None else None
        if rng is not None and is_tuple:
            rng.sep = True
        notes = []
        if default is not None and "default:" not in help_:
            notes.append("default: " + (",".join(map(str, default)) if isinstance(default, tuple) else str(default)))
        if rng is not None and not is_tuple:
            notes.append(rng.short())
        kw["help"] = help_ + (f" ({'; '.join(notes)})" if notes else "")
        if origin is typing.Literal:
            kw["choices"] = list(args)
            kw["type"] = type(args[0])
            if f.metadata.get("const") is not None:  # the flag alone means this choice (``--texture``: on)
                kw["nargs"], kw["const"] = "?", f.metadata["const"]
        elif f.metadata.get("parse"):  # a text setting with its own check (raises argparse.ArgumentTypeError)
            kw["type"] = f.metadata["parse"]
        elif rng is not None:
            kw["type"] = rng
        elif kind is not None:
            kw["type"] = _parse_tuple if is_tuple else Ranged(kind)  # no declared range: finite values
        elif origin in (typing.Union, types.UnionType):
            inner = [a for a in args if a is not type(None)]
            kw["type"] = inner[0]
        else:
            kw["type"] = tp
        if origin is not typing.Literal:  # choices show as {a,b,c}
            kw["metavar"] = f.metadata.get("metavar") or (
                "X,Y,Z,..." if is_tuple else "N" if kind is int else "X" if kind is float else "TEXT")
        _finish(parser, parser.add_argument(*flags, **kw), prefix, f, kw)


def _finish(parser, action: argparse.Action, prefix: str, f: dataclasses.Field, kw: dict | None = None) -> None:
    """A config field's flag once added: hidden when it is a tuning setting (its help kept as ``tuning_help``
    for docs/cli.md), and its former names (``RENAMED``) added as hidden aliases."""
    action.tuning_help = None
    if is_tuning(prefix, f):
        action.tuning_help, action.help = action.help, argparse.SUPPRESS
    taken = parser._option_string_actions
    plain = field_flag(f)
    for old, name in RENAMED.get(prefix, {}).items():
        if name != f.name:
            continue
        if kw is None:  # pragma: no cover - no boolean was renamed
            raise TypeError(f"{f.name}: a renamed boolean needs its --no- form too")
        old_plain = "--" + old.replace("_", "-")
        aliases = [o for o in (old_plain, f"--{prefix}.{old_plain[2:]}") if o not in taken]
        if aliases:
            cls = type("_Renamed", (_Renamed,), {"new_plain": plain if plain in action.option_strings else
                                                 f"--{prefix}.{plain[2:]}", "new_prefixed": f"--{prefix}.{plain[2:]}"})
            alias = parser.add_argument(*aliases, **{**kw, "help": argparse.SUPPRESS}, action=cls)
            alias.renamed_to = cls.new_plain
    for old, (name, value) in RENAMED_TO_VALUE.get(prefix, {}).items():
        if name != f.name:
            continue
        old_plain = "--" + old.replace("_", "-")
        forms = (old_plain, "--no-" + old_plain[2:], f"--{prefix}.{old_plain[2:]}", f"--no-{prefix}.{old_plain[2:]}")
        aliases = [o for o in forms if o not in taken]
        if aliases:
            new_plain = plain if plain in action.option_strings else f"--{prefix}.{plain[2:]}"
            cls = type("_RenamedToValue", (_RenamedToValue,), {
                "value": value, "new_plain": f"{new_plain} {value}", "new_prefixed": f"--{prefix}.{plain[2:]} {value}"})
            alias = parser.add_argument(*aliases, dest=action.dest, help=argparse.SUPPRESS, action=cls)
            alias.renamed_to = cls.new_plain
            alias.renamed_note = f"--no-{old_plain[2:]}: the default, changes nothing"


def renamed_warnings(args: argparse.Namespace, prefix: str) -> None:
    """Log, once each, the former flags of config ``prefix`` that the command line used."""
    import logging

    left = []
    for old, new, dest in getattr(args, "_renamed", None) or ():
        if dest.startswith(prefix + ".") and new is None:  # --no-FLAG of a RENAMED_TO_VALUE flag
            logging.getLogger("photorecon").warning("%s is the default now and changes nothing (the setting is --%s)",
                                                    old, dest.split(".", 1)[1].replace("_", "-"))
        elif dest.startswith(prefix + "."):
            logging.getLogger("photorecon").warning("%s is now %s (the former name still works, for now)", old, new)
        else:
            left.append((old, new, dest))
    if getattr(args, "_renamed", None):
        args._renamed = left


def _parse_tuple(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.replace(",", " ").split())
    except ValueError:
        values = ()
    if not values or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers separated by commas, got {text!r}")
    return values


def config_prefix(config_cls) -> str:
    """``MVSConfig`` -> ``mvs``, ``FusionConfig`` -> ``fusion`` (or the class's ``CLI_PREFIX``)."""
    name = getattr(config_cls, "CLI_PREFIX", None) or config_cls.__name__.removesuffix("Config")
    return name.lower()


def _dest(prefix: str, name: str) -> str:
    return f"{prefix}.{name}"


def _forced(args: argparse.Namespace, prefix: str) -> dict:
    """The values of config ``prefix`` that a former boolean flag set (``force``), by field name."""
    return {dest.split(".", 1)[1]: value for dest, value in (getattr(args, "_forced", None) or {}).items()
            if dest.startswith(prefix + ".")}


def config_from_args(config_cls, args: argparse.Namespace, **overrides):
    """The config ``config_cls`` from the values ``add_config_arguments`` parsed into ``args`` (plus
    ``overrides``), checked by ``validate`` (which a config's own ``__post_init__`` runs too)."""
    prefix = config_prefix(config_cls)
    renamed_warnings(args, prefix)
    values_in = vars(args)
    values = {f.name: values_in[_dest(prefix, f.name)] for f in dataclasses.fields(config_cls)
              if _dest(prefix, f.name) in values_in}
    values.update({name: value for name, value in _forced(args, prefix).items() if name in values})
    values.update(overrides)
    cfg = config_cls(**values)
    validate(cfg)
    return cfg


# --- commands ---------------------------------------------------------------------------------------------
COMMANDS: dict[str, typing.Callable[[argparse._SubParsersAction], None]] = {}


def command(fn):
    """Register a function ``fn(subparsers)`` that adds one sub-command."""
    COMMANDS[fn.__name__] = fn
    return fn
