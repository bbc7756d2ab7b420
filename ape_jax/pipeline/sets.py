"""The `--set SECTION.FIELD=VALUE` language over a sweep's records (`ape_jax.pipeline.presets` applies it to its
protocol, budget and recipe: `presets.parse_set`, `format_set`, `fields`, where callers read it).

    section, field, value = parse_set(records, "recipe.batch_size=64")   # ("recipe", "batch_size", 64)
    format_set(records, "protocol", "image_size", (32, 32))               # "protocol.image_size=32,32"
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any
from collections.abc import Mapping

from ape_jax.pipeline import method_knobs
from ape_jax.pipeline.hints import SettingsError, describe as _describe, format_value as _format
from ape_jax.pipeline.hints import image_size as _image_size, parse as _parse

# fields whose text is read by a reader of their own, not by their type: an image size reads as every --image-size
# flag reads it (a single N is square), which `tuple[int, int]` alone cannot say
_TEXT_READERS = {("protocol", "image_size"): _image_size}


def fields(records: Mapping[str, type], section: str) -> tuple[str, ...]:
    """The fields `--set` can change in `section` of `records` (`{section: record class}`): every field but the
    record's name and description."""
    return tuple(f.name for f in dataclasses.fields(records[section]) if f.name not in ("name", "doc", "reference"))


def parse_set(records: Mapping[str, type], item: str) -> tuple[str, str, Any]:
    """`"SECTION.FIELD=VALUE"` -> `(section, field, value)`, the value parsed by the field's type.

    Values: numbers as written; `none` for an optional field; lists comma-separated (`0.1,0.2`), the step
    grid's settings as `THR:W` (`0.1:5,0.2:3`), an image size as `N` (square), `HxW` or `H,W`
    (`hints.image_size`, as every `--image-size` flag).
    """
    key, sep, text = item.partition("=")
    section, dot, field = key.strip().partition(".")
    if not sep or not dot:
        raise SettingsError(f"--set {item!r} is not SECTION.FIELD=VALUE (e.g. recipe.batch_size=64)")
    if section not in records and method_knobs.owns(section):
        return section, field, method_knobs.parse_set(section, field, text, item)
    if section == "recipe" and field in method_knobs.LEGACY:  # a method's knob under its old recipe name
        return section, field, method_knobs.parse_legacy(field, text, item)
    if section not in records:
        raise SettingsError(f"--set {item!r}: unknown section {section!r}; valid: {', '.join(records)} or a method "
                            f"with settings of its own")
    if field not in fields(records, section):
        raise SettingsError(f"--set {item!r}: unknown field {section}.{field}; valid: "
                            + ", ".join(f"{section}.{f}" for f in fields(records, section)))
    hint = typing.get_type_hints(records[section])[field]
    own = _TEXT_READERS.get((section, field))
    if own is not None and text.strip().lower() not in ("none", "null"):
        try:
            return section, field, own(text.strip())
        except ValueError as e:
            raise SettingsError(f"--set {item!r}: {e}, or none (the task's own)") from None
    try:
        return section, field, _parse(hint, text.strip())
    except (TypeError, ValueError) as e:
        raise SettingsError(f"--set {item!r}: {section}.{field} takes {_describe(hint)}: {e}") from None


def format_set(records: Mapping[str, type], section: str, field: str, value: Any) -> str:
    """`"SECTION.FIELD=VALUE"` that `parse_set` reads back as `value` (its inverse)."""
    return f"{section}.{field}={_format(typing.get_type_hints(records[section])[field], value)}"
