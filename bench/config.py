"""Declarative checks of the files users write (pydantic v2 models), reported as one-line :class:`ConfigError`.

A file type is a :class:`Section` model (nested models per section): unknown keys are refused (``extra="forbid"``),
types are strict (an int is accepted for a float, a bool for neither, a float not for an int), floats must be
finite, ranges and choices are ``Field`` constraints and ``Literal`` types, plausibility checks are validators.
:func:`parse` validates a mapping and returns it as nested dicts with every default filled in; the first problem
becomes ``ConfigError(source, dotted.key, message)`` - the same one line as everywhere else, never pydantic's dump.

A validator that checks one key against another raises :class:`KeyProblem` to name the key at fault (relative to
the model it validates); a plain ``ValueError`` names the model's own key.
"""

from __future__ import annotations

import copy
import difflib
import math
import types
import typing
from typing import Annotated, Any, Literal

import yaml
from pydantic import AfterValidator, BaseModel, ConfigDict, Field, PlainValidator, ValidationError
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError

from bench.errors import ConfigError

#: unit carried by a key's name (longest suffix first)
UNITS = (("_per_mm2", "1/mm²"), ("_per_mm4", "1/mm⁴"), ("_per_mm", "1/mm"), ("_mm", "mm"), ("_deg", "deg"),
         ("_rad", "rad"), ("_px", "px"), ("_pct", "%"), ("_m", "m"), ("_s", "s"))


def unit_of(key: str) -> str:
    """The unit a (dotted) key's last name carries by its suffix, e.g. ``"mm"`` for ``lab.tracker_sigma_mm``."""
    leaf = str(key).rsplit(".", 1)[-1]
    return next((u for s, u in UNITS if leaf.endswith(s)), "")


class Section(BaseModel):
    """Base of every model of a user file: unknown keys refused, strict types, finite floats."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)


class KeyProblem(ValueError):
    """Raised by a validator to blame ``key`` (dotted, relative to the validated model) with ``problem``."""

    def __init__(self, key: str, problem: str):
        super().__init__(problem)
        self.key, self.problem = key, problem


def section(model: type[Section]):
    """A field holding the section ``model``, all of its defaults when the file leaves it out."""
    return Field(default_factory=model)


def _number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PydanticCustomError("number_type", "expected a number")
    if not math.isfinite(value):
        raise PydanticCustomError("finite_number", "must be finite")
    return value


#: an int or a float, kept as given (a list of them is written back unchanged: ``[20, 30]`` stays ints)
Number = Annotated[int | float, PlainValidator(_number, json_schema_input_type=float)]
PositiveFloat = Annotated[float, Field(gt=0)]
NonNegFloat = Annotated[float, Field(ge=0)]
PositiveInt = Annotated[int, Field(ge=1)]
NonNegInt = Annotated[int, Field(ge=0)]
PositiveNumber = Annotated[Number, Field(gt=0)]
Vec2 = Annotated[list[Number], Field(min_length=2, max_length=2)]
Vec3 = Annotated[list[Number], Field(min_length=3, max_length=3)]


def about(text: str):
    """``Field(description=text)``: a key's meaning, shown in ``docs/reference.md``."""
    return Field(description=text)


#: ``imaging_params`` of the rendering kinds: a stage's parameters replaced (checked by bench.sim.imaging)
ImagingParams = Annotated[dict[str, dict], about(
    "stage -> {parameter: value} replacing the realistic profile's (bench.sim.imaging.REALISTIC)")]


def _plausible(limit, problem, op):
    ok = {"<=": lambda v: v <= limit, "<": lambda v: v < limit, ">=": lambda v: v >= limit, ">": lambda v: v > limit}
    test = ok[op]

    def check(v):
        if not test(v):
            raise ValueError(problem.format(v=v))
        return v

    check.constraint = f"plausible {op} {_g(limit)}"  # for the reference
    return AfterValidator(check)


def at_most(limit: float, problem: str, strict: bool = False):
    """Plausibility check: a value above ``limit`` (``strict``: or at it) is refused with ``problem`` (``{v}`` is the
    value)."""
    return _plausible(limit, problem, "<" if strict else "<=")


def at_least(limit: float, problem: str, strict: bool = False):
    """Plausibility check: a value below ``limit`` (``strict``: or at it) is refused with ``problem`` (``{v}`` is the
    value)."""
    return _plausible(limit, problem, ">" if strict else ">=")


def distinct(values: list) -> list:
    """Validator of a list whose values must differ."""
    if len(set(values)) != len(values):
        raise ValueError(f"expected distinct values, got {values!r}")
    return values


Distinct = AfterValidator(distinct)


# ------------------------------------------------------------------------------------------------ parsing


def parse(model: type[Section], data, source, at: str = "") -> dict:
    """Check a parsed file (or a part of one) against its model.

    Parameters
    ----------
    model : type of Section
        The file's model.
    data : object
        The parsed YAML (normally a mapping).
    source : str or Path
        The file, named by the error.
    at : str
        The dotted key of ``data`` inside its file when ``data`` is a part of it, prefixed to the error's key.

    Returns
    -------
    dict
        ``data`` validated, as nested dicts (lists, numbers, strings) with every default filled in.

    Raises
    ------
    ConfigError
        The first problem, one line: ``<source>: <dotted.key>: <problem>`` (an unknown key before any other).
    """
    try:
        return model.model_validate(data).model_dump()
    except ValidationError as exc:
        err = config_error(exc, model, data, source)
        if at:
            err = ConfigError(source, at if err.field == "<top>" else f"{at}.{err.field}", err.problem)
        raise err from None


def _annotated(ann):
    """``(bare type, constraint metadata)`` of a possibly ``Annotated``, possibly optional type."""
    meta = []
    while True:
        if typing.get_origin(ann) is Annotated:
            args = typing.get_args(ann)
            ann = args[0]
            for m in args[1:]:
                meta += m.metadata if isinstance(m, FieldInfo) else [m]
        elif isinstance(ann, types.UnionType) or typing.get_origin(ann) is typing.Union:
            args = [a for a in typing.get_args(ann) if a is not type(None)]
            if len(args) != 1:
                return ann, meta
            ann = args[0]
        else:
            return ann, meta


def resolve(model, loc) -> tuple:
    """``(type, metadata)`` of the field or list item of ``model`` at ``loc`` (``(None, [])`` if not a field)."""
    ann, meta = model, []
    for part in loc:
        if isinstance(part, str) and isinstance(ann, type) and issubclass(ann, BaseModel):
            field = ann.model_fields.get(part)
            if field is None:
                return None, []
            ann, meta = field.annotation, list(field.metadata)
        elif isinstance(part, int) and typing.get_args(ann):
            ann, meta = typing.get_args(ann)[0], []
        else:
            return None, []
        ann, more = _annotated(ann)
        meta += more
    return ann, meta


def _g(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


#: the longest value an error message shows whole (a file's whole text, read as one string, would fill the screen)
SHOWN_CHARS = 80


def _shown(value) -> str:
    """``repr(value)``, cut to :data:`SHOWN_CHARS` with its length said when longer."""
    r = repr(value)
    return r if len(r) <= SHOWN_CHARS else f"{r[:SHOWN_CHARS - 3]}... ({len(r)} characters)"


def choices_text(choices) -> str:
    """``a`` / ``a or b`` / ``one of a, b, c``."""
    words = [str(c) for c in choices]
    return words[0] if len(words) == 1 else " or ".join(words) if len(words) == 2 else "one of " + ", ".join(words)


def bounds_text(meta, unit: str = "") -> str:
    """The range of ``meta`` (``>= 0 mm``, ``300..5000 mm``, ``(0.2, 3) m``); empty without bounds."""
    b = {k: getattr(m, k) for m in meta for k in ("gt", "ge", "lt", "le") if getattr(m, k, None) is not None}
    lo = ("ge", b["ge"]) if "ge" in b else ("gt", b["gt"]) if "gt" in b else None
    hi = ("le", b["le"]) if "le" in b else ("lt", b["lt"]) if "lt" in b else None
    unit = f" {unit}" if unit else ""
    if lo and hi:
        if lo[0] == "ge" and hi[0] == "le":
            return f"{_g(lo[1])}..{_g(hi[1])}{unit}"
        return f"{'[' if lo[0] == 'ge' else '('}{_g(lo[1])}, {_g(hi[1])}{']' if hi[0] == 'le' else ')'}{unit}"
    op = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    return next((f"{op[k]} {_g(v)}{unit}" for k, v in (lo, hi) if k), "") if (lo or hi) else ""


def _length_text(meta) -> str:
    lo = next((m.min_length for m in meta if getattr(m, "min_length", None) is not None), None)
    hi = next((m.max_length for m in meta if getattr(m, "max_length", None) is not None), None)
    if lo is not None and lo == hi:
        return f"{lo} values"
    if hi is None:
        return "a non-empty list" if lo == 1 else f"at least {lo} values"
    return f"{lo or 0}..{hi} values"


_TYPES = {"float_type": "float", "int_type": "int", "bool_type": "bool", "string_type": "str", "list_type": "list",
          "dict_type": "a mapping", "model_type": "a mapping", "number_type": "a number"}


def _path(loc) -> str:
    """``('views', 2, 'name')`` -> ``views[2].name``."""
    return "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc).lstrip(".")


def message(err: dict, model, data) -> tuple[str, str]:
    """The dotted key and the one-line problem of one pydantic error.

    Parameters
    ----------
    err : dict
        An item of ``ValidationError.errors()`` (``type``, ``loc``, ``msg``, ``input``, ``ctx``).
    model : type of BaseModel
        The model validated, to find the constraints, choices and known keys at ``loc``.
    data : object
        The data validated, to quote the whole list when an item of it is at fault.

    Returns
    -------
    key : str
        ``section.key``; ``views[2].name`` inside a list of mappings; a list of values is named by its key and the
        item by the problem (``(item 2 of [...])``), so the key is what ``--set`` takes.
    problem : str
        The message in the user's words and units, e.g. ``must be > 0 mm, got -1``.
    """
    loc, kind, value = err["loc"], err["type"], err.get("input")
    error = (err.get("ctx") or {}).get("error")
    if isinstance(error, KeyProblem):
        loc = (*loc, *error.key.split("."))
    first = next((i for i, p in enumerate(loc) if isinstance(p, int)), len(loc))
    key_loc, items = list(loc[:first]), list(loc[first:])
    if any(isinstance(p, str) for p in items):  # a list of mappings: the path names the item (views[2].name)
        key_loc, items = [_path(loc)], []
    ann, meta = resolve(model, loc)
    key = ".".join(str(p) for p in key_loc) or "<top>"
    if kind == "invalid_key":  # a YAML key that is not a string (1:, true:): unknown, whatever it is
        node = data
        for part in loc[:-1]:
            node = node.get(part, {}) if isinstance(node, dict) else {}
        bad = [k for k in node if not isinstance(k, str)] if isinstance(node, dict) else []
        return _path(loc[:-1]) or "<top>", f"unknown key {(bad or [loc[-1]])[0]!r} (keys are names)"
    if kind == "extra_forbidden":
        parent, _ = resolve(model, loc[:-1])
        names = list(parent.model_fields) if isinstance(parent, type) and issubclass(parent, BaseModel) else []
        prefix = _path(loc[:-1]) + "." if loc[:-1] else ""
        close = difflib.get_close_matches(str(loc[-1]), names, n=1)
        problem = "unknown key" + (f" (did you mean '{prefix}{close[0]}'?)" if close
                                   else f" (allowed: {', '.join(names)})")
    elif kind == "missing":
        while isinstance(ann, type) and issubclass(ann, BaseModel):  # a section left out: its first required key
            name = next((n for n, f in ann.model_fields.items() if f.is_required()), None)
            if name is None:
                break
            key, ann = f"{key}.{name}", _annotated(ann.model_fields[name].annotation)[0]
        problem = "missing"
    elif kind in _TYPES:
        problem = f"expected {_TYPES[kind]}, got {type(value).__name__} {_shown(value)}"
    elif kind == "finite_number":
        problem = f"must be finite, got {_shown(value)}"
    elif kind == "literal_error":
        problem = f"expected {choices_text(typing.get_args(ann))}, got {_shown(value)}"
    elif kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        text = bounds_text(meta or [type("B", (), err["ctx"])], unit_of(key))
        problem = (f"expected {text}, got {_g(value)}" if ".." in text
                   else f"must be {'in ' if text.startswith(('(', '[')) else ''}{text}, got {_g(value)}")
    elif kind in ("too_short", "too_long", "string_too_short"):
        what = "a non-empty string" if isinstance(value, str) else _length_text(meta)
        problem = f"expected {what}, got {_shown(value)}"
    elif error is not None:
        problem = str(error)
    else:
        problem = err["msg"]
    if items:
        whole = data
        for p in key_loc:
            whole = whole.get(p) if isinstance(whole, dict) else None
        where = ", ".join(str(i + 1) for i in items if isinstance(i, int))
        problem += f" (item {where} of {_shown(whole)})"
    return key, problem


def config_error(exc: ValidationError, model, data, source) -> ConfigError:
    """The first error of ``exc`` as a one-line :class:`ConfigError` naming ``source`` and the dotted key (an unknown
    key first: a misspelt key is also a missing one, and the unknown one says which)."""
    errors = exc.errors(include_url=False)
    key, problem = message(next((e for e in errors if e["type"] == "extra_forbidden"), errors[0]), model, data)
    return ConfigError(source, key, problem)


# ------------------------------------------------------------------------------------------------ the model as data


def leaves(model: type[BaseModel], prefix: str = ""):
    """``(dotted key, FieldInfo)`` of every leaf field of ``model``, sections flattened, in declaration order."""
    for name, field in model.model_fields.items():
        ann, _ = _annotated(field.annotation)
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            yield from leaves(ann, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", field


def type_text(ann) -> str:
    """A short name of a field's type for the reference (``float``, ``list of number``, ``one of a, b``)."""
    bare, _ = _annotated(ann)
    inner = typing.get_args(ann)[0] if typing.get_origin(ann) is Annotated else ann  # Annotated nests flat
    optional = bare is not ann and type(None) in typing.get_args(inner)
    if typing.get_origin(bare) is Literal:
        text = choices_text(typing.get_args(bare))
    elif typing.get_origin(bare) is list:
        text = "list of " + type_text(typing.get_args(bare)[0]) if typing.get_args(bare) else "list"
    elif typing.get_origin(bare) is dict or bare is dict:
        text = "mapping"
    elif isinstance(bare, types.UnionType) and set(typing.get_args(bare)) == {int, float}:
        text = "number"
    else:
        text = getattr(bare, "__name__", str(bare))
    return f"{text} or null" if optional else text


def constraint_text(field: FieldInfo, unit: str = "") -> str:
    """The declared constraints of a field: its range, length, and those of its items."""
    bare, meta = _annotated(field.annotation)
    meta = list(field.metadata) + meta
    parts = [bounds_text(meta, unit)] + [m.func.constraint for m in meta if hasattr(getattr(m, "func", None),
                                                                                   "constraint")]
    if any(getattr(m, "min_length", None) is not None for m in meta):
        parts.append(_length_text(meta))
    if typing.get_origin(bare) is list and typing.get_args(bare):
        item_meta = _annotated(typing.get_args(bare)[0])[1]
        item = "; ".join(p for p in [bounds_text(item_meta, unit)] + [
            m.func.constraint for m in item_meta if hasattr(getattr(m, "func", None), "constraint")] if p)
        parts.append(f"items {item}" if item else "")
    return "; ".join(p for p in parts if p)


def default_of(field: FieldInfo) -> Any:
    """A field's default (``...`` when required)."""
    if field.is_required():
        return ...
    if field.default_factory is not None:
        return field.default_factory()
    return field.default


# ------------------------------------------------------------------------------------------------ files, overrides


def parse_set(item: str, source: str = "--set") -> tuple:
    """``"key=value"`` of ``--set`` -> ``(key, value parsed as YAML)``; one-line :class:`ConfigError` naming
    ``source`` otherwise."""
    if "=" not in item:
        raise ConfigError(source, item, "--set expects KEY=VALUE")
    key, raw = item.split("=", 1)
    try:
        return key.strip(), yaml.safe_load(raw)
    except yaml.YAMLError:
        raise ConfigError(source, key, f"--set value {raw!r} is not valid YAML") from None


def apply_overrides(data: dict, overrides, source: str) -> dict:
    """Apply ``["a.b=1", ...]`` (values parsed as YAML, :func:`parse_set`) to a raw mapping; returns a new mapping."""
    data = copy.deepcopy(data)
    for item in overrides or []:
        key, value = parse_set(item, source)
        node = data
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ConfigError(source, key, f"'{part}' is not a section")
        node[parts[-1]] = value
    return data


def load_yaml(path) -> dict:
    """Parse a YAML mapping; one-line :class:`ConfigError` if missing, unreadable or not a mapping."""
    from bench.fileio import read_yaml

    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(path, "<file>", "expected a mapping at the top level")
    return data


class MmDeg(Section):
    """``units: {length: mm, angle: deg}`` of a file whose keys carry their units (the only units written)."""

    length: Literal["mm"] = "mm"
    angle: Literal["deg"] = "deg"


class PlotOutputs(Section):  # ``outputs`` of a kind that only plots
    plots: bool = True


class RenderOutputs(Section):  # ``outputs`` of a kind that renders: the render cache, the plots, the recording
    cache: bool = True
    plots: bool = True
    rerun: bool = True


class ScenarioBase(Section):
    """The keys every scenario file has; a kind's model adds its sections."""

    name: str
    kind: str
    description: str = ""
    seed: NonNegInt = 0
