"""The one typed configuration loader: frozen dataclasses from YAML, every failure one line naming file and key.

A configuration is a frozen dataclass whose fields carry type hints; this module turns a parsed YAML document into
it and nothing else in the project parses configuration. Supported hints: bool, int, float, str, Path, Optional
(`X | None`), unions tried in order, `tuple[X, ...]`, fixed `tuple[X, Y]`, `Literal[...]`, `dict[str, X]` and
nested dataclasses (an absent or null section means its defaults). Checks that go beyond the type (ranges, choices
that depend on other fields) live in the dataclass's `__post_init__`, so a config built in code is checked too.

Field metadata tunes one field:
- `parse`: a callable `(value) -> value` run instead of the type's coercion (e.g. hex strings for USB ids); it
  raises ValueError with the rest of the sentence ("must be ...").
- `internal`: True for a field the program fills (a file's digest, its folder): a file naming it is refused.
- `empty_ok`: True for a text field that may be empty (text is non-empty otherwise: an empty value is a mistake).

YAML comes from outside (an operator's file, a study from a lab): it is read with bounded nesting, so `[[[[...` or
an integer of thousands of digits is a one-line error (`YAMLLimitError`), not a RecursionError.

Values: bool is only true/false (never 1 or "yes"); int is never a bool; float takes ints and numeric strings
(PyYAML reads `1e-3` as a string) but never NaN or infinity; Path expands `~` and, given `base_dir`, is resolved
against the config file's folder. Errors are raised as the caller's own exception class (`error=`), so each
package keeps its hierarchy; an exception from a nested dataclass's own checks that is not of that class (another
package's config nested inside) gets the section's name in front.

firmware_bridge imports nothing of ours, so it carries a byte-identical copy of this file
(`firmware_bridge/config_loader.py`); a test keeps the two the same.
"""
from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import yaml

MAX_CONFIG_BYTES = 1 << 20
MAX_DEPTH = 32   # configs nest 3 or 4 levels deep
_NUMBER_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\Z")
_NONE_TEXT = ("", "null", "none", "~")
_PLAIN_KEY_RE = re.compile(r"[A-Za-z0-9_.-]{1,64}\Z")


def load_yaml(path: str | Path, *, error: type[Exception], what: str = "config") -> dict[str, Any]:
    """The mapping in a YAML file (an empty file is an empty mapping); errors name the file."""
    return parse_yaml(read_bytes(path, error=error, what=what), path, error=error)


def read_bytes(path: str | Path, *, error: type[Exception], what: str = "config") -> bytes:
    """A config file's bytes (for a caller that also records their digest); errors name the file."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise error(f"{path}: {len(data)} bytes is too large for a {what}")
    return data


def parse_yaml(data: bytes, path: str | Path, *, error: type[Exception]) -> dict[str, Any]:
    """The mapping in a config file's bytes (`path` names it in errors)."""
    try:
        doc = safe_load(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise error(f"{path}: not UTF-8 text") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({one_line(str(exc))})") from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise error(f"{path}: the top level must be a mapping of sections, got {_describe(doc)}")
    return doc


def build(cls: type, data: Any, *, error: type[Exception], base_dir: Path | None = None,
          where: str | None = None, internal: Mapping[str, Any] | None = None) -> Any:
    """An instance of dataclass `cls` from a parsed document; `where` (a file) is put in front of any error.
    `internal` gives the values of the fields the program fills (metadata `internal`), as they are."""
    try:
        return _build(cls, {} if data is None else data, "", _Ctx(error, base_dir), internal or {})
    except error as exc:
        if where is None:
            raise
        raise error(f"{where}: {exc}") from None


def load(cls: type, path: str | Path | None, *, error: type[Exception], overrides: Mapping | None = None,
         what: str = "config") -> Any:
    """Read a YAML file (or none: defaults), merge `overrides` in by section, build `cls`. Relative paths in the
    file start at its folder. A section an override touches must be valid in the file too: an option that hides a
    bad value today leaves the program unable to start the day it runs without that option."""
    doc = load_yaml(path, error=error, what=what) if path is not None else {}
    where = str(path) if path is not None else "the command line"
    base_dir = None if path is None else Path(path).parent
    touched = [k for k in (overrides or {}) if isinstance(doc.get(k), Mapping)]
    try:
        check_sections(cls, doc, touched, error=error, base_dir=base_dir)
    except error as exc:
        raise error(f"{where}: {exc}") from None
    return build(cls, merge(doc, overrides or {}), error=error, base_dir=base_dir, where=where)


def check_sections(cls: type, doc: Mapping, names: Iterable[str], *, error: type[Exception],
                   base_dir: Path | None = None) -> None:
    """Build the named sections (dataclass fields of `cls`) of `doc` on their own; errors name the section's key."""
    hints, fields = typing.get_type_hints(cls), {f.name: f for f in dataclasses.fields(cls)}
    for name in names:
        if name in fields and dataclasses.is_dataclass(hints[name]):
            _value(fields[name], name, doc[name], hints[name], _Ctx(error, base_dir))


class YAMLLimitError(yaml.YAMLError):
    """A document that is well-formed YAML but no sane config: nested too deeply, or a value too large."""


class BoundedLoader(yaml.SafeLoader):
    """SafeLoader that refuses documents nested deeper than `max_depth` collections (PyYAML composes nested
    collections recursively, so deep nesting would otherwise end in a RecursionError)."""

    max_depth = MAX_DEPTH

    def compose_node(self, parent, index):  # type: ignore[override]
        self._depth = getattr(self, "_depth", 0) + 1
        try:
            if self._depth > self.max_depth:
                line = self.peek_event().start_mark.line + 1
                raise YAMLLimitError(f"nested deeper than {self.max_depth} levels (line {line})")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def safe_load(text: str | bytes) -> Any:
    """`yaml.safe_load` with bounded nesting; every failure is a `yaml.YAMLError` with a one-line message."""
    try:
        return yaml.load(text, Loader=BoundedLoader)  # noqa: S506 - BoundedLoader is a SafeLoader
    except RecursionError:
        raise YAMLLimitError("nested too deeply") from None
    except ValueError as exc:   # int() of more than 4300 digits, and the like
        raise YAMLLimitError(f"holds a value that cannot be read ({one_line(str(exc), 100)})") from None


def one_line(text: str, limit: int = 200) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def merge(doc: Mapping, overrides: Mapping) -> dict:
    """`doc` with `overrides` laid over it, section by section (a mapping merges, anything else replaces)."""
    out = dict(doc)
    for k, v in overrides.items():
        out[k] = merge(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def parse_overrides(cls: type, items: Iterable[str], *, error: type[Exception]) -> dict:
    """`section.key=value` items (a command line's `--set`) as a nested mapping of typed values for `cls`.

    The text after `=` is read as the field's type: verbatim for strings and paths, YAML for the rest, and a
    comma-separated list for tuples (`optim.betas=0.5,0.9`)."""
    out: dict = {}
    for item in items:
        if "=" not in item:
            raise error(f"--set {item!r} must be section.key=value")
        dotted, text = (s.strip() for s in item.split("=", 1))
        parts = dotted.split(".")
        target, hint, prefix = cls, None, ""
        for i, part in enumerate(parts):
            if target is None or not dataclasses.is_dataclass(target):
                raise error(f"--set {item}: {prefix.rstrip('.')} is a setting, not a section")
            names = _loadable(target)
            if part not in names:
                where = f" in {prefix.rstrip('.')}" if prefix else ""
                raise error(f"--set {item}: unknown key(s){where}: {part} (valid: {', '.join(names)})")
            hint = typing.get_type_hints(target)[part]
            prefix += part + "."
            target = hint if i < len(parts) - 1 else None
        field = {f.name: f for f in dataclasses.fields(_owner(cls, parts))}[parts[-1]]
        if dataclasses.is_dataclass(hint):
            raise error(f"--set {item}: {dotted} is a section; set one of its keys")
        value: Any
        if text.lower() in _NONE_TEXT and _optional(hint):
            value = None
        elif _base(hint) in (str, Path) or "parse" in field.metadata:
            value = text
        else:
            try:
                value = safe_load(text)
            except yaml.YAMLError:
                value = text
            if typing.get_origin(_base(hint)) is tuple and isinstance(value, str):
                try:
                    value = [safe_load(t) for t in value.split(",")]
                except yaml.YAMLError:
                    pass
        try:
            value = _value(field, dotted, value, hint, _Ctx(error, None))
        except error as exc:
            raise error(f"--set {item}: {exc}") from None
        cur = out
        for p in parts[:-1]:
            cur = cur.setdefault(p, {})
        cur[parts[-1]] = value
    return out


def to_mapping(obj: Any) -> Any:
    """A config as plain YAML-ready data (tuples -> lists, paths -> strings); `build` reads it back."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if not f.metadata.get("internal")}
    if isinstance(obj, Mapping):
        return {k: to_mapping(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


class _Ctx(typing.NamedTuple):
    error: type[Exception]
    base_dir: Path | None


def _loadable(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.init and not f.metadata.get("internal")]


def _owner(cls: type, parts: list[str]) -> type:
    for part in parts[:-1]:
        cls = typing.get_type_hints(cls)[part]
    return cls


def _key_text(key: Any) -> str:
    """A key as an error shows it: as written when it is a plain name, quoted and cut short otherwise (a key from
    a hostile file must not break the one-line message)."""
    text = str(key)
    return text if _PLAIN_KEY_RE.match(text) else ascii(text)[:40]


def _describe(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if value is None:
        return "nothing"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _optional(hint: Any) -> bool:
    return typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in typing.get_args(hint)


def _base(hint: Any) -> Any:
    """`X` for `X | None`; the hint itself otherwise."""
    if _optional(hint):
        rest = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(rest) == 1:
            return rest[0]
    return hint


def _build(cls: type, data: Any, prefix: str, ctx: _Ctx, internal: Mapping[str, Any] | None = None) -> Any:
    where = prefix.rstrip(".")
    if not isinstance(data, Mapping):
        raise ctx.error(f"{where or 'the top level'} must be a mapping{' of sections' if not where else ''}, "
                        f"got {_describe(data)}")
    names = _loadable(cls)
    unknown = sorted(_key_text(k) for k in data if k not in names)
    if unknown:
        raise ctx.error(f"unknown key(s){f' in {where}' if where else ''}: {', '.join(unknown)} "
                        f"(valid: {', '.join(names)})")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    missing = [n for n in names if n not in data and fields[n].default is dataclasses.MISSING
               and fields[n].default_factory is dataclasses.MISSING]
    if missing:
        raise ctx.error(f"missing key(s){f' in {where}' if where else ''}: {', '.join(sorted(missing))}")
    hints = typing.get_type_hints(cls)
    kwargs = {name: _value(fields[name], f"{prefix}{name}", value, hints[name], ctx) for name, value in data.items()}
    kwargs.update(internal or {})
    try:
        return cls(**kwargs)
    except ctx.error:
        raise
    except (ValueError, TypeError) as exc:
        raise ctx.error(f"{where + ': ' if where else ''}{exc}") from None
    except Exception as exc:
        if getattr(exc, "user_facing", False):  # another package's config error, from a section nested here
            raise ctx.error(f"{where + ': ' if where else ''}{exc}") from None
        raise


def _value(field: dataclasses.Field, key: str, value: Any, hint: Any, ctx: _Ctx) -> Any:
    parse = field.metadata.get("parse")
    if parse is None:
        if value == "" and isinstance(value, str) and _base(hint) is str and not field.metadata.get("empty_ok"):
            raise ctx.error(f"{key} must be a non-empty string")
        return _coerce(key, value, hint, ctx)
    if value is None and _optional(hint):
        return None
    try:
        return parse(value)
    except ValueError as exc:
        raise ctx.error(f"{key} {exc}") from None


def _coerce(key: str, value: Any, hint: Any, ctx: _Ctx) -> Any:
    err = ctx.error
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return _build(hint, {} if value is None else value, key + ".", ctx)
    if origin in (typing.Union, types.UnionType):
        if value is None:
            if type(None) in typing.get_args(hint):
                return None
            raise err(f"{key} must not be empty")
        options = [a for a in typing.get_args(hint) if a is not type(None)]
        for option in options[:-1]:
            try:
                return _coerce(key, value, option, ctx)
            except err:
                continue
        return _coerce(key, value, options[-1], ctx)
    if value is None:
        raise err(f"{key} must not be empty")
    if origin is typing.Literal:
        choices = typing.get_args(hint)
        if value not in choices or isinstance(value, bool) != isinstance(choices[0], bool):
            raise err(f"{key} must be one of {', '.join(map(str, choices))}, got {_describe(value)}")
        return value
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, (list, tuple)):
            raise err(f"{key} must be a list, got {_describe(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(f"{key}[{i}]", v, args[0], ctx) for i, v in enumerate(value))
        if len(value) != len(args):
            raise err(f"{key} must be a list of {len(args)} values, got {len(value)}")
        return tuple(_coerce(f"{key}[{i}]", v, a, ctx) for i, (v, a) in enumerate(zip(value, args)))
    if origin is dict or hint is dict:
        kt, vt = typing.get_args(hint) or (str, Any)
        if not isinstance(value, Mapping):
            raise err(f"{key} must be a mapping, got {_describe(value)}")
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise err(f"{key} keys must be strings, got {_describe(k)}")
            out[k] = v if vt is Any else _coerce(f"{key}.{_key_text(k)}", v, vt, ctx)
        return out
    if hint is bool:
        if not isinstance(value, bool):
            raise err(f"{key} must be true or false, got {_describe(value)}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise err(f"{key} must be an integer, got {_describe(value)}")
        return value
    if hint is float:
        number = value
        if isinstance(value, str) and _NUMBER_RE.match(value.strip()):
            number = float(value)
        if isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number):
            raise err(f"{key} must be a finite number, got {_describe(value)}")
        return float(number)
    if hint is str:
        if not isinstance(value, str):
            raise err(f"{key} must be a string, got {_describe(value)}")
        return value
    if hint is Path:
        if not isinstance(value, (str, Path)) or not str(value) or "\0" in str(value):
            raise err(f"{key} must be a path, got {_describe(value)}")
        p = Path(value).expanduser()
        return p if ctx.base_dir is None or p.is_absolute() else ctx.base_dir / p
    if hint is Any:
        return value
    raise err(f"{key}: unsupported setting type {hint!r}")  # a bug in the dataclass, not in the file
