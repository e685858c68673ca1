"""Strict TOML configuration: unknown keys and wrong types fail at start, naming the key."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import math
import os
import re
import stat
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Iterator, TypeVar

T = TypeVar("T")
# a config file read at start is at most this long (the largest written, a [frame.sites] or [regions] table of
# many entries, is kilobytes): a larger one, or one that is no regular file, is refused unread
MAX_CONFIG_BYTES = 16 * 2**20


class ConfigError(ValueError):
    """A configuration value is missing, unknown or invalid; the message names the key."""


def did_you_mean(name: str, choices: typing.Iterable[str], prefix: str = "") -> str:
    """``": did you mean PREFIXchoice?"`` for the closest of ``choices`` to a mistyped ``name``
    (difflib, similarity at least 0.6), else ``""``: the near-miss hint of every unknown key or field."""
    close = difflib.get_close_matches(name, list(choices), n=1)
    return f": did you mean {prefix}{close[0]}?" if close else ""


def seed_number(text: str) -> int:
    """``--seed``: a whole number >= 0 (numpy's generators refuse a negative seed: it was a traceback)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 0, got {text!r}")
    return value


def finite_number(text: str) -> float:
    """A ``fedtrack serve`` option's seconds (``--health-period``, ``--deadline``, ``--start-at`` ...): a finite
    number (``nan`` passed every ``<= 0`` check before the tour60 session, and ``--connect-timeout nan`` ended in
    a traceback)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def require_finite_keys(record: object, keys: typing.Iterable[str]) -> None:
    """Refuse TOML's ``inf``, ``-inf`` and ``nan`` in ``record``'s number (or nested tuple of numbers) ``keys``:
    ``inf`` passes a ``> 0`` check and ``nan`` a ``< 0`` one (tour61, tour62)."""
    def numbers(value: Any) -> typing.Iterator[float]:
        if isinstance(value, tuple):
            for v in value:
                yield from numbers(v)
        elif value is not None:
            yield value

    for key in keys:
        value = getattr(record, key)
        if not all(math.isfinite(v) for v in numbers(value)):
            shown = f"{value:g}" if isinstance(value, float) else str(value)
            raise ConfigError(f"{key}: must be a finite number, got {shown}")


def read_small_file(path: Path, limit: int, what: str) -> bytes | None:
    """The bytes of the regular file ``path`` (``what`` it is, for the errors), None when there is none;
    ConfigError for one that cannot be read, is not a regular file (opened without blocking: a FIFO
    would block the start for good) or is longer than ``limit`` bytes (read no further: a link to
    /dev/zero was read until a MemoryError)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise ConfigError(f"{path}: not a regular file, not a {what}")
    with os.fdopen(fd, "rb") as fh:
        try:
            raw = fh.read(limit + 1)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    if len(raw) > limit:
        raise ConfigError(f"{path}: larger than {limit} bytes, not a {what}")
    return raw


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file (at most ``MAX_CONFIG_BYTES``), turning parse errors into :class:`ConfigError`."""
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, not a config file")
    raw = read_small_file(p, MAX_CONFIG_BYTES, "config file")
    if raw is None:
        raise ConfigError(f"config file {p} does not exist")
    try:
        return tomllib.loads(raw.decode())
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: invalid TOML: not UTF-8 text (byte {exc.start})") from exc
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        reason = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
        raise ConfigError(f"{p}: invalid TOML: {reason}") from exc


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{key}: invalid value {value!r}")
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {value!r}")
        key_type, value_type = args if args else (str, Any)
        return {_coerce(k, key_type, key): _coerce(v, value_type, f"{key}.{k}") for k, v in value.items()}
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {type(value).__name__}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{key}: expected {len(args)} items, got {len(value)}")
            return tuple(_coerce(v, a, f"{key}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        inner = args[0] if args else Any
        items = [_coerce(v, inner, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if annotation is Any:
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {value!r}")
        return parse_dataclass(annotation, value, key)
    raise ConfigError(f"{key}: unsupported type {annotation!r}")


def parse_dataclass(cls: type[T], table: dict[str, Any], where: str = "") -> T:
    """Build dataclass ``cls`` from a TOML table.

    Unknown keys, wrong types and (if the class defines ``validate()``) invalid values
    raise :class:`ConfigError` with the dotted key name. Missing keys take the
    dataclass defaults.
    """
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    prefix = f"{where}." if where else ""
    unknown = sorted(set(table) - set(fields))
    if unknown:
        hint = did_you_mean(str(unknown[0]), fields, prefix)
        raise ConfigError(f"unknown config key {prefix}{unknown[0]!s}"
                          + (hint or f" (allowed: {', '.join(sorted(fields))})"))
    kwargs = {}
    for name, value in table.items():
        kwargs[name] = _coerce(value, hints[name], f"{prefix}{name}")
    for name, f in fields.items():
        if name not in kwargs and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"missing config key {prefix}{name}")
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        try:
            validate()
        except ConfigError as exc:
            raise ConfigError(f"{prefix}{exc}") from exc
    return obj


#: The top-level tables of the one configuration file read by ``replay``, ``serve`` and
#: ``launch``. Each consumer parses the tables it uses (:func:`load_tables`); the others must
#: be known names, so that a typo still fails.
TABLES = ("fusion", "deployment", "sensor", "sonar", "radar", "radar_filter", "imm", "pda", "mtt", "multitarget",
          "zenoh", "frame", "regions")


@contextlib.contextmanager
def in_file(path: str | Path | None) -> Iterator[None]:
    """Prefix a :class:`ConfigError` raised inside the block with ``path`` (``FILE: ...``); not one that names
    an environment variable (``$NAME: ...``), which the file did not set."""
    try:
        yield
    except ConfigError as exc:
        if path is None or str(exc).startswith((f"{path}:", "$")):
            raise
        raise ConfigError(f"{path}: {exc}") from exc


def load_tables(path: str | Path | None, schema: type[T]) -> T:
    """Parse the tables of dataclass ``schema`` from the config file (defaults when ``path`` is None).

    Tables of :data:`TABLES` that ``schema`` does not hold are left to the services that use
    them; any other top-level name is an error. Errors name the file, the table and the key
    (``FILE: unknown config key imm.foo ...``).
    """
    if path is None:
        return schema()
    data = load_toml(path)
    own = {f.name for f in dataclasses.fields(schema)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - own - set(TABLES))
    with in_file(path):
        if unknown:
            tables = set(TABLES) | own
            raise ConfigError(f"unknown config key {unknown[0]}"
                              + (did_you_mean(unknown[0], tables) or f" (tables: {', '.join(sorted(tables))})"))
        return parse_dataclass(schema, {k: v for k, v in data.items() if k in own})


def to_toml(table: dict[str, Any]) -> str:
    """Serialize a (nested) dict of scalars, lists, tables and lists of tables to TOML text."""
    lines: list[str] = []

    def fmt(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, float)):
            return repr(float(v)) if isinstance(v, float) else str(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        raise TypeError(f"cannot write {type(v).__name__} to TOML")

    def is_array_of_tables(v: Any) -> bool:
        return isinstance(v, (list, tuple)) and bool(v) and all(isinstance(x, dict) for x in v)

    def key(k: str) -> str:
        return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else fmt(k)

    def dotted(tbl: dict[str, Any], prefix: str) -> dict[str, Any] | None:
        """``tbl``'s leaves as dotted keys under ``prefix`` when it holds only scalars and tables of
        them (no arrays of tables), else None."""
        flat: dict[str, Any] = {}
        for k, v in tbl.items():
            if isinstance(v, dict):
                sub = dotted(v, f"{prefix}.{key(k)}")
                if sub is None:
                    return None
                flat.update(sub)
            elif is_array_of_tables(v):
                return None
            elif v is not None:
                flat[f"{prefix}.{key(k)}"] = v
        return flat

    def emit(tbl: dict[str, Any], path: str, header: str = "") -> None:
        scalars = {key(k): v for k, v in tbl.items()
                   if not isinstance(v, dict) and not is_array_of_tables(v) and v is not None}
        if path:  # a top-level table's sub-tables as dotted keys inside it: keys appended to the file land in it
            for k, v in list(tbl.items()):
                flat = dotted(v, key(k)) if isinstance(v, dict) else None
                if flat is not None:
                    scalars.update(flat)
                    tbl = {kk: vv for kk, vv in tbl.items() if kk != k}
        tables = {k: v for k, v in tbl.items() if isinstance(v, dict)}
        arrays = {k: v for k, v in tbl.items() if is_array_of_tables(v)}
        if header or (path and (scalars or not (tables or arrays))):
            lines.append(header or f"[{path}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {fmt(v)}")
        if scalars or header:
            lines.append("")
        for k, v in tables.items():
            emit(v, f"{path}.{k}" if path else k)
        for k, items in arrays.items():
            for item in items:
                sub = f"{path}.{k}" if path else k
                emit(item, sub, f"[[{sub}]]")

    emit(table, "")
    return "\n".join(lines).rstrip() + "\n"
