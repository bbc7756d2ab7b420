"""Settings' values by their type hints: checked and converted from Python or JSON (`coerce`), read from
command-line text (`parse`) and written back as text that `parse` reads (`format_value`). The settings records
(`ape_jax.pipeline.presets`) type every field; this is how `--set section.field=value` and results files become
those types, and how `SettingsError` says what a field cannot take."""

from __future__ import annotations

import re
import types
import typing
from typing import Any

IMAGE_SIZE_FORMS = "N, HxW or H,W (positive integers)"  # what `image_size` reads, for the messages that name it


class SettingsError(ValueError):
    """An unknown preset, recipe or field, or a value a field cannot take (one line)."""


def check(ok: bool, message: str) -> None:
    """Raises `SettingsError(message)` unless `ok`."""
    if not ok:
        raise SettingsError(message)


def coerce(hint: Any, value: Any, name: str) -> Any:
    """`value` (from Python or JSON) as type `hint`: lists to tuples; a wrong type is a `SettingsError`."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if value is None:
        check(type(None) in typing.get_args(hint), f"{name} cannot be none")
        return None
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return coerce(args[0], value, name)
    if origin is tuple:
        check(isinstance(value, (list, tuple)), f"{name} must be a list, got {value!r}")
        inner = typing.get_args(hint)
        if len(inner) == 2 and inner[1] is Ellipsis:
            return tuple(coerce(inner[0], v, name) for v in value)
        check(len(value) == len(inner), f"{name} must have {len(inner)} entries, got {value!r}")
        return tuple(coerce(h, v, name) for h, v in zip(inner, value))
    if hint is bool:
        check(isinstance(value, bool), f"{name} must be true or false, got {value!r}")
    elif hint is int:
        check(isinstance(value, int) and not isinstance(value, bool), f"{name} must be an integer, got {value!r}")
    elif hint is float:
        check(isinstance(value, (int, float)) and not isinstance(value, bool),
               f"{name} must be a number, got {value!r}")
        value = float(value)
    elif hint is str:
        check(isinstance(value, str), f"{name} must be a string, got {value!r}")
    return value


def parse(hint: Any, text: str) -> Any:
    """Command-line text as type `hint` (`presets.parse_set`)."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if text.lower() in ("none", "null") and type(None) in typing.get_args(hint):
        return None
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return parse(args[0], text)
    if origin is tuple:
        inner = typing.get_args(hint)
        if len(inner) == 2 and inner[1] is Ellipsis:
            items = [t.strip() for t in text.split(",") if t.strip()]
            if typing.get_origin(inner[0]) is tuple:  # pairs: THR:W
                return tuple(tuple(parse(h, p) for h, p in zip(typing.get_args(inner[0]), pair(t)))
                             for t in items)
            return tuple(parse(inner[0], t) for t in items)
        parts = [t.strip() for t in text.replace("x", ",").split(",")]
        if len(parts) != len(inner):
            raise ValueError(f"{text!r} has {len(parts)} entries, not {len(inner)}")
        return tuple(parse(h, p) for h, p in zip(inner, parts))
    if hint is bool:
        if text.lower() not in ("true", "false"):
            raise ValueError(f"{text!r} is not true or false")
        return text.lower() == "true"
    if hint is int:
        try:
            return int(text)
        except ValueError:  # int()'s own words ("invalid literal ... base 10") say nothing a user typed
            raise ValueError(f"{text!r} is not a whole number") from None
    if hint is float:
        try:
            return float(text)
        except ValueError:
            raise ValueError(f"{text!r} is not a number") from None
    return text


def image_size(text: str) -> tuple[int, int]:
    """An image size as typed on a command line, `N` (square), `HxW` or `H,W`, as `(height, width)`.

    The one reader of every `--image-size` flag and of `--set protocol.image_size=...`, so they all take the same
    forms. Raises `ValueError("an image size is N, HxW or H,W (positive integers)")`; the caller names the flag and
    the text, which the message leaves out.
    """
    parts = [p.strip() for p in re.split(r"[x,]", str(text).strip().lower())]
    if len(parts) not in (1, 2) or not all(p.isascii() and p.isdigit() and int(p) > 0 for p in parts):
        raise ValueError(f"an image size is {IMAGE_SIZE_FORMS}")
    return int(parts[0]), int(parts[-1])


def format_value(hint: Any, value: Any) -> str:
    """`value` as command-line text that `parse(hint, ...)` reads back."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if value is None:
        return "none"
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return format_value(args[0], value)
    if origin is tuple:
        inner = typing.get_args(hint)
        if len(inner) == 2 and inner[1] is Ellipsis:
            if typing.get_origin(inner[0]) is tuple:  # pairs: THR:W
                return ",".join(":".join(format_value(h, v) for h, v in zip(typing.get_args(inner[0]), pair))
                                for pair in value)
            return ",".join(format_value(inner[0], v) for v in value)
        return ",".join(format_value(h, v) for h, v in zip(inner, value))
    if hint is bool:
        return "true" if value else "false"
    if hint is float:
        return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else repr(float(value))
    return str(value)


def pair(text: str) -> list[str]:
    parts = text.split(":")
    if len(parts) != 2:
        raise ValueError(f"{text!r} is not THR:W (e.g. 0.1:5)")
    return parts


def describe(hint: Any) -> str:
    return str(hint).replace("typing.", "").replace("<class '", "").replace("'>", "")
