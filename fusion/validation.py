"""Readable messages for pydantic validation errors.

One wording for every typed YAML input — meta.yaml, fusion configs, plugin options and simulator
scenarios: each problem names its dotted key path (``filter.covariance_step_s``,
``plugins[0].sigma_scale``) and the rule broken, and an unknown key gets the nearest valid key
and the list of valid keys at that place.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence
from types import UnionType
from typing import Annotated, Any, Union, get_args, get_origin

import annotated_types
from pydantic import BaseModel, ValidationError


def dotted(path: Iterable[Any]) -> str:
    """``("plugins", 0, "gate")`` → ``"plugins[0].gate"``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out


def _unwrap(tp: Any) -> Any:
    while True:
        origin = get_origin(tp)
        if origin is Annotated:
            tp = get_args(tp)[0]
        elif origin in (Union, UnionType):
            args = [a for a in get_args(tp) if a is not type(None)]
            if len(args) != 1:
                return tp
            tp = args[0]
        else:
            return tp


def model_at(root: type[BaseModel], path: Sequence[Any]) -> type[BaseModel] | None:
    """The model class found at ``path`` inside ``root`` (None if not a model)."""
    tp: Any = root
    for part in path:
        tp = _unwrap(tp)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            info = tp.model_fields.get(str(part))
            if info is None:
                return None
            tp = info.annotation
        elif get_origin(tp) in (dict, list):
            tp = get_args(tp)[-1]
        else:
            return None
    tp = _unwrap(tp)
    return tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def suggest(word: str, options: Sequence[str]) -> str | None:
    """The option closest to ``word`` (case-insensitive), or None when none is near."""
    lower = {o.lower(): o for o in options}
    hit = difflib.get_close_matches(word.lower(), list(lower), n=1, cutoff=0.6)
    return lower[hit[0]] if hit else None


def short_repr(value: Any) -> str:
    """``repr`` cut to 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def allowed_interval(root: type[BaseModel], path: Sequence[Any]) -> str | None:
    """The range a numeric field at ``path`` inside ``root`` allows, as an interval such as
    ``[0.001, 10]`` or ``(0, 1)``; None unless the field is bounded on both sides."""
    if not path:
        return None
    model = model_at(root, path[:-1])
    info = model.model_fields.get(str(path[-1])) if model is not None else None
    if info is None:
        return None
    low = high = None
    for rule in info.metadata:
        if isinstance(rule, annotated_types.Gt):
            low = f"({rule.gt:g}"
        elif isinstance(rule, annotated_types.Ge):
            low = f"[{rule.ge:g}"
        elif isinstance(rule, annotated_types.Lt):
            high = f"{rule.lt:g})"
        elif isinstance(rule, annotated_types.Le):
            high = f"{rule.le:g}]"
    return f"{low}, {high}" if low is not None and high is not None else None


def describe_error(root: type[BaseModel], err: Any) -> str:
    """A sentence for one pydantic error dict of a ``root`` model validation."""
    kind = err["type"]
    loc = err["loc"]
    value = err.get("input")
    ctx = err.get("ctx") or {}
    if kind == "missing":
        return "required key is missing"
    if kind == "extra_forbidden":
        key = str(loc[-1])
        model = model_at(root, loc[:-1])
        valid = sorted(model.model_fields) if model is not None else []
        hint = suggest(key, valid)
        rule = f"unknown key {key!r}"
        if hint:
            rule += f" (did you mean {hint!r}?)"
        if valid:
            rule += f"; valid keys here: {', '.join(valid)}"
        if not loc[:-1] and "extra" in root.model_fields:
            rule += "; free-form entries belong under 'extra:'"
        return rule
    if kind == "literal_error":
        return f"must be {ctx.get('expected')} (found {short_repr(value)})"
    if kind in ("float_type", "float_parsing"):
        return f"must be a number (found {short_repr(value)})"
    bounds = {
        "greater_than": ">",
        "greater_than_equal": ">=",
        "less_than": "<",
        "less_than_equal": "<=",
    }
    if kind == "finite_number" or kind in bounds:
        interval = allowed_interval(root, loc)
        if interval is not None:
            return f"must be a number in {interval} (found {short_repr(value)})"
        if kind == "finite_number":
            return f"must be a finite number (found {short_repr(value)})"
        limit = next(iter(ctx.values()))
        return f"must be {bounds[kind]} {limit:g} (found {short_repr(value)})"
    if kind in ("tuple_type", "list_type"):
        return f"must be a list (found {short_repr(value)})"
    if kind == "too_long":
        return f"must have {ctx.get('max_length')} items (found {ctx.get('actual_length')})"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"must be a mapping of keys to values (found {short_repr(value)})"
    if kind == "string_type":
        return f"must be a string (found {short_repr(value)})"
    if kind == "value_error":
        return str(err["msg"]).removeprefix("Value error, ")
    return str(err["msg"])


def error_lines(
    source: str,
    root: type[BaseModel],
    error: ValidationError,
    prefix: Sequence[str | int] = (),
) -> list[str]:
    """One line per problem: ``source: key a.b[0].c: rule``; ``prefix`` is prepended to paths."""
    lines = []
    for err in error.errors():
        path = dotted((*prefix, *err["loc"])) or "(top level)"
        lines.append(f"{source}: key {path}: {describe_error(root, err)}")
    return lines
