"""Shared CLI plumbing: user errors become one line on stderr and exit status 2, whether they
are a malformed override, a value of the wrong type or a bad input found later."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import io
import os
import sys
import typing
from pathlib import Path
from typing import Callable, TypeVar

from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import ConfigCompositionException, HydraException, MissingConfigException, OverrideParseException
from omegaconf import BooleanNode, DictConfig, FloatNode, IntegerNode, OmegaConf, StringNode
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException, ValidationError

from motiongen.errors import ConfigError, MotiongenError

F = TypeVar("F", bound=Callable)

CONFIG_DIR = Path(__file__).resolve().parent / "configs"     # train / sample / evaluate .yaml


def _register_resolvers() -> None:
    """`${mg.default:${out},runs/...}` in the Hydra configs: the value, or the default when it
    is null. (oc.select falls back only for a *missing* key; `out: null` is present.)"""
    if not OmegaConf.has_resolver("mg.default"):
        OmegaConf.register_new_resolver("mg.default", lambda value, default: default if value is None else value)


_register_resolvers()     # every Hydra entry point imports this module before hydra.main runs


INTERRUPTED = 130      # 128 + SIGINT: the status a shell gives a program that Ctrl-C ended


class Interrupted(KeyboardInterrupt):
    """A Ctrl-C that knows what the run leaves behind: its message ends the one line
    `interrupted: <message>` (e.g. the last checkpoint to resume from)."""


def ending_line(e: BaseException) -> str | None:
    """The one line a run ended by `e` prints instead of a traceback: `error: ...` for a user
    error, `interrupted[: ...]` for Ctrl-C; None for anything else (a bug keeps its traceback)."""
    if isinstance(e, MotiongenError):
        return f"error: {e}"
    if isinstance(e, KeyboardInterrupt):
        return "interrupted" + (f": {e}" if str(e) else "")
    return None


def user_errors_exit_2(fn: F) -> F:
    """Wrap a CLI entry point so a `MotiongenError` prints `error: <message>` and exits 2, and
    Ctrl-C prints `interrupted[: <what is left>]` and exits 130, each one line, no traceback.

    Hydra catches exceptions raised inside a `@hydra.main` function and prints its own
    traceback, so apply this *inside* (below) `@hydra.main`: the function exits before Hydra
    sees anything.
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (MotiongenError, KeyboardInterrupt) as e:
            # Ctrl-C under torchrun reaches every rank: rank 0 alone says so (and where to resume).
            if not (isinstance(e, KeyboardInterrupt) and os.environ.get("RANK", "0") not in ("", "0")):
                print(ending_line(e), file=sys.stderr, flush=True)
            sys.exit(2 if isinstance(e, MotiongenError) else INTERRUPTED)

    return wrapper  # type: ignore[return-value]


def tool_main(run: Callable[[list[str]], object], report: Callable[[object], None] | None = None) -> Callable:
    """The `main(argv=None)` of a small tool: `run(argv)` (sys.argv[1:] by default), then
    `report(result)`; a user error is one line and exit status 2, Ctrl-C one line and exit
    status 130 (`user_errors_exit_2`)."""

    @user_errors_exit_2
    def main(argv: list[str] | None = None) -> int:
        result = run(sys.argv[1:] if argv is None else list(argv))
        if report is not None:
            report(result)
        return 0

    return main


def _hydra_flags() -> argparse.ArgumentParser:
    """The flags `hydra.main` takes besides overrides (`--cfg job`, `-m`, `--config-name NAME`
    ...), so that the arguments left over are the overrides."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("overrides", nargs="*")
    for flag in (["--help", "-h"], ["--hydra-help"], ["--version"], ["--resolve"], ["--run", "-r"],
                 ["--multirun", "-m"], ["--shell-completion", "-sc"]):
        parser.add_argument(*flag, action="store_true")
    for flag in (["--package", "-p"], ["--config-path", "-cp"], ["--config-name", "-cn"],
                 ["--config-dir", "-cd"], ["--experimental-rerun"]):
        parser.add_argument(*flag)
    parser.add_argument("--cfg", "-c", choices=["job", "hydra", "all"])
    parser.add_argument("--info", "-i", nargs="?", const="all",
                        choices=["all", "config", "defaults", "defaults-tree", "plugins", "searchpath"])
    return parser


def check_hydra_overrides(argv: list[str] | None = None, config_name: str | None = None,
                          config_dir=None) -> Path | None:
    """Exit 2 with one line if a command-line override of a Hydra app is malformed.

    Hydra parses overrides inside `hydra.main`, before our function (and so
    `user_errors_exit_2`) runs, and reports a grammar error as several lines plus a
    HYDRA_FULL_ERROR hint, exit 1. Call this before `hydra.main`: it splits argv with the flags
    Hydra takes (so `--cfg job` or `-m` are left alone) and parses each override with Hydra's
    own grammar.

    With `config_name` and `config_dir` (motiongen/configs), the overrides are also composed
    against the config once (about a tenth of a second), so an unknown key, a value of the wrong
    type or a missing option of a config group is one line and exit 2 too, instead of Hydra's
    message and exit 1, and the run directory they compose to is returned (None where nothing
    was composed). Sweeps (`-m`, `a=1,2`) are left to Hydra.
    """
    argv = sys.argv[1:] if argv is None else argv
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            args, _ = _hydra_flags().parse_known_args(argv)
    except SystemExit:
        return None                 # a bad flag: Hydra's own usage message says it
    parser = OverridesParser.create()
    parsed = []
    for override in args.overrides:
        try:
            parsed += parser.parse_overrides([override])
        except OverrideParseException as e:
            # Hydra's message: the reason, a caret line for lexer errors, a link to its docs.
            lines = [ln.strip() for ln in str(e).splitlines()]
            reason = "; ".join(ln for ln in lines if ln and not ln.startswith("See https://")
                               and set(ln) != {"^"} and not ln.startswith("Error parsing override"))
            print(f"error: malformed override {override!r}: {reason or 'not valid override syntax'}",
                  file=sys.stderr, flush=True)
            sys.exit(2)
    if config_name is not None and config_dir is not None and not args.multirun \
            and not any(o.is_sweep_override() for o in parsed):
        return _check_composes(list(args.overrides), config_name, config_dir)
    return None


def _check_composes(overrides: list[str], config_name: str, config_dir) -> Path | None:
    """The run directory `hydra.run.dir` the overrides compose to (None where it does not
    resolve here); exit 2 with one line where they do not compose."""
    try:
        with initialize_config_dir(config_dir=str(Path(config_dir).resolve()), version_base="1.3"):
            cfg = compose(config_name, overrides=overrides, return_hydra_config=True)
            run_dir = OmegaConf.select(cfg, "hydra.run.dir", throw_on_resolution_failure=False)
            return Path(run_dir) if run_dir else None
    except MissingConfigException as e:
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
        options = [ln for ln in lines[2:] if not ln.startswith(("Config search path", "provider="))]
        head = lines[0].split(": ", 1)[-1] if lines else "missing config"
        print(f"error: {head}" + (f"; available: {', '.join(options)}" if options else ""),
              file=sys.stderr, flush=True)
        sys.exit(2)
    except ConfigCompositionException as e:
        if isinstance(e.__cause__, ValidationError):
            print(f"error: {value_error(e.__cause__)}", file=sys.stderr, flush=True)
            sys.exit(2)
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
        msg = "; ".join(lines[:2]) if lines else "cannot apply the overrides"
        if msg.startswith("Could not override"):
            msg = "unknown key: " + msg
        print(f"error: {msg} (see --cfg job for the keys)", file=sys.stderr, flush=True)
        sys.exit(2)


# The small tools parse `key=value` arguments with Hydra's own override grammar and check each
# value with OmegaConf's typed nodes, as the Hydra apps' structured configs do, so quoting,
# lists, `+key` and type errors behave the same at every entry point.
_KIND_WORDS = {int: "an integer", float: "a number", bool: "true or false", list: "a list [a,b,...]", str: "a value"}
_NODES = {int: IntegerNode, float: FloatNode, bool: BooleanNode, str: StringNode}


def _field_kind(e: OmegaConfBaseException) -> type | None:
    """int, float, bool or str: the type of the dataclass field a refused value was meant for
    (None for a list item or a field of another type)."""
    owner = OmegaConf.get_type(e.parent_node) if e.parent_node is not None else None
    if not (dataclasses.is_dataclass(owner) and isinstance(e.key, str)):
        return None
    hint = typing.get_type_hints(owner).get(e.key)
    kinds = [k for k in typing.get_args(hint) if k is not type(None)] or [hint]
    return kinds[0] if len(kinds) == 1 and kinds[0] in _NODES else None


def value_error(e: OmegaConfBaseException) -> str:
    """One line for a value OmegaConf refused for a typed field: `key: expected <kind>, got <value>`
    (OmegaConf's own first line where the field is not a number, a flag or a string)."""
    kind = _field_kind(e)
    if kind is None:
        return f"{e.full_key}: {str(e.msg).splitlines()[0]}"
    return f"{e.full_key}: expected {_KIND_WORDS[kind]}, got {e.value!r}"


def typed_config(schema, values, prefix: str = ""):
    """An instance of dataclass `schema` from a mapping of its keys (a dotlist's DictConfig, a
    dict), each value converted or refused as a Hydra app's structured config does; an unknown
    key or a refused value is a ConfigError naming `prefix` + the key."""
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(schema), values))
    except ConfigKeyError as e:
        keys = ", ".join(schema.__dataclass_fields__)
        raise ConfigError(f"{prefix}{e.key}: not a key here ({keys})") from None
    except ValidationError as e:
        raise ConfigError(prefix + value_error(e)) from None


def _typed(kind, value):
    """value checked and converted as OmegaConf does for a config field of this type."""
    if value is None:
        return None
    if kind is list:
        if not isinstance(value, list):
            raise ValueError(value)
        return [str(v) for v in value]
    return DictConfig({"value": _NODES[kind](value=value)}).value


def _quoted_list(parser, key: str, value: str):
    """A list whose items hold characters the grammar reserves (`thresholds=[right_foot=700]`):
    the same items quoted, or None when that does not parse either."""
    v = value.strip()
    if not (v.startswith("[") and v.endswith("]")) or any(c in v[1:-1] for c in "[]'\"\\"):
        return None
    items = [i.strip() for i in v[1:-1].split(",") if i.strip()]
    try:
        return parser.parse_override(f"{key}=[{','.join(repr(i) for i in items)}]")
    except HydraException:
        return None


def tool_help(spec: dict, usage: str = "", doc: str = "", required: tuple[str, ...] = ()) -> str:
    """The `--help` text of a small tool: what it does, its usage and every key with its type and
    default."""
    lines = [doc.strip(), ""] if doc.strip() else []
    if usage:
        lines += [f"usage: {usage}", ""]
    lines.append("keys (key=value; Hydra override syntax: lists [a,b], quote values with spaces):")
    width = max(len(k) for k in spec) if spec else 0
    for key, (kind, default, *rest) in spec.items():
        shown = "(required)" if key in required else f"default: {'null' if default is None else default}"
        lines.append(f"  {key:<{width}}  {kind.__name__:<5}  {shown}" + (f"  {rest[0]}" if rest else ""))
    return "\n".join(lines)


def parse_key_values(argv: list[str], spec: dict[str, tuple], required: tuple[str, ...] = (),
                     usage: str = "", doc: str = "") -> dict:
    """Parse ``key=value`` arguments for the small (non-Hydra) tools.

    spec maps each key to (type, default) or (type, default, help) with type one of str, int,
    float, bool, list (of strings: ``[a,b]``; a bare ``a`` or ``a,b`` is read as a list too).
    Values use Hydra's override grammar (``null``, quoting, ``+key``) and are checked against the
    types as OmegaConf does for the Hydra scripts. ``--help`` / ``-h`` prints `tool_help` and
    exits 0. Unknown keys, bad values and missing required keys raise ConfigError (exit 2 in CLIs).
    """
    if any(a in ("--help", "-h") for a in argv):
        print(tool_help(spec, usage, doc, required))
        sys.exit(0)
    hint = f" (usage: {usage})" if usage else f" (keys: {', '.join(spec)})"
    out = {k: (list(d) if isinstance(d, list) else d) for k, (_, d, *_) in spec.items()}
    parser = OverridesParser.create()
    for arg in argv:
        key, eq, value = arg.partition("=")
        key = key.lstrip("+")
        if not eq:
            raise ConfigError(f"argument {arg!r}: expected key=value{hint}")
        if key not in spec:
            raise ConfigError(f"unknown key {key!r}; expected one of {', '.join(spec)}")
        kind = spec[key][0]
        if kind is list and not value.strip().startswith("["):
            value = f"[{value}]"                        # inputs=a.bvh, inputs=a.bvh,b.bvh
        try:
            override = parser.parse_override(f"{key}={value}")
        except HydraException as e:
            override = _quoted_list(parser, key, value) if kind is list else None
            if override is None:
                why = str(e).splitlines()[0] if str(e) else "cannot parse"
                raise ConfigError(f"{key}={value!r}: {why}") from None
        if override.is_sweep_override():
            raise ConfigError(f"{key}={value!r}: expected one value, not a sweep")
        parsed = override.value()
        if kind is str and isinstance(parsed, (bool, int, float)):
            parsed = value.strip()                       # out=007, name=1e3: the text as typed
        if parsed == "" and kind is not list:
            raise ConfigError(f"{key}= is empty: expected {_KIND_WORDS[kind]}")
        try:
            out[key] = _typed(kind, parsed)
        except (OmegaConfBaseException, ValueError):
            raise ConfigError(f"{key}={value!r}: expected {_KIND_WORDS[kind]}") from None
    for key in required:
        if out.get(key) in (None, "", []):
            raise ConfigError(f"missing {key}=...{hint}")
    return out
