"""Scenario files: load, validate against a schema, apply ``--set key=value`` overrides.

A schema is a nested dict whose leaves are ``(type, default)``; ``type`` is one of ``int``, ``float``, ``bool``,
``str``, ``list``. An unknown or mistyped key is a :class:`ConfigError` naming the file and the dotted key.
"""

from __future__ import annotations

import copy
import difflib
from pathlib import Path

import yaml

from bench.errors import ConfigError

_REQUIRED = object()


def required(kind):
    """Schema leaf for a key that has no default."""
    return (kind, _REQUIRED)


def _type_ok(kind, value):
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


def _validate(data, schema, source, prefix=""):
    if not isinstance(data, dict):
        raise ConfigError(source, prefix.rstrip(".") or "<top>", "expected a mapping")
    out = {}
    for key in data:
        if key not in schema:
            close = difflib.get_close_matches(str(key), list(schema), n=1)
            hint = f" (did you mean '{prefix}{close[0]}'?)" if close else f" (allowed: {', '.join(schema)})"
            raise ConfigError(source, f"{prefix}{key}", "unknown key" + hint)
    for key, spec in schema.items():
        path = f"{prefix}{key}"
        if isinstance(spec, dict):
            out[key] = _validate(data.get(key, {}), spec, source, path + ".")
            continue
        kind, default = spec
        if key not in data:
            if default is _REQUIRED:
                raise ConfigError(source, path, "missing")
            out[key] = copy.deepcopy(default)
            continue
        value = data[key]
        if not _type_ok(kind, value):
            raise ConfigError(source, path, f"expected {kind.__name__}, got {type(value).__name__} {value!r}")
        if kind is float:
            value = float(value)
            if value != value or value in (float("inf"), float("-inf")):
                raise ConfigError(source, path, "must be finite")
        out[key] = value
    return out


def validate(data: dict, schema: dict, source: str) -> dict:
    """Validated copy of ``data`` with defaults filled in."""
    return _validate(data, schema, source)


def apply_overrides(data: dict, overrides, source: str) -> dict:
    """Apply ``["a.b=1", ...]`` (values parsed as YAML) to a raw scenario mapping; returns a new mapping."""
    data = copy.deepcopy(data)
    for item in overrides or []:
        if "=" not in item:
            raise ConfigError(source, item, "--set expects KEY=VALUE")
        key, raw = item.split("=", 1)
        try:
            value = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(source, key, f"--set value {raw!r} is not valid YAML") from None
        node = data
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(source, key, f"'{part}' is not a section")
        node[parts[-1]] = value
    return data


def load_yaml(path) -> dict:
    """Parse a YAML mapping; one-line :class:`ConfigError` if missing, unreadable or not a mapping."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, "<file>", "not found")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(path, "<file>", f"not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ConfigError(path, "<file>", "expected a mapping at the top level")
    return data
