"""Methods' own settings on the command line and in results: `--set METHOD.KNOB=VALUE`.

    knobs = parse_sets(["ptp.weights=0.5,1", "ptp.past=3"])   # {"ptp": {"weights": (0.5, 1.0), "past": 3}}
    records = build(knobs)                                    # {"ptp": PtpKnobs(weights=(0.5, 1.0), past=3)}
    to_json(records)                                          # results.json's `settings.knobs`

A method that declares a `Method.knobs` record (a frozen dataclass in its own module: its fields typed, its
defaults the authors', its values checked in `__post_init__`) owns those settings: the sweep takes them as
`--set METHOD.KNOB=VALUE`, parsed by the field's type hint as every `--set` is (`ape_jax.pipeline.hints`),
records the ones it was given in results.json beside the three records (`settings.knobs`, only where set, so
the settings of every earlier file stay as they were), and hands them to the method's grid and learner
(`GridContext.knobs`, `ctx.knobs_of(name)`). Nothing else lists a method's knobs.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterable, Mapping
from typing import Any

from ape_jax import methods
from ape_jax.pipeline.hints import SettingsError, coerce, describe, format_value, parse


def owns(section: str) -> bool:
    """Whether `section` of a `--set SECTION.FIELD=VALUE` names a method with settings of its own."""
    try:
        return methods.get(section).knobs is not None
    except methods.MethodError:
        return False


def _hints(method: str) -> dict[str, Any]:
    record = methods.get(method).knobs
    return {f.name: typing.get_type_hints(record)[f.name] for f in dataclasses.fields(record)}


def parse_set(method: str, field: str, text: str, item: str) -> Any:
    """The value of `--set METHOD.FIELD=TEXT` (`item`, for the message) by the field's type; `SettingsError`,
    one line, for an unknown field or a value it cannot take."""
    hints = _hints(method)
    if field not in hints:
        raise SettingsError(f"--set {item!r}: {method} has no setting {field!r}; valid: "
                            + ", ".join(f"{method}.{f}" for f in hints))
    try:
        return parse(hints[field], text.strip())
    except (TypeError, ValueError) as e:
        raise SettingsError(f"--set {item!r}: {method}.{field} takes {describe(hints[field])}: {e}") from None


def format_set(method: str, field: str, value: Any) -> str:
    """`"METHOD.FIELD=VALUE"` that `parse_set` reads back as `value`."""
    return f"{method}.{field}={format_value(_hints(method)[field], value)}"


def build(values: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """`{method: {field: value}}` as `{method: its knobs record}`, each checked by the record (`SettingsError`, one
    line, naming the method); a method with no values gets none (it runs at its defaults)."""
    out = {}
    for method, fields in values.items():
        if not fields:
            continue
        if not owns(method):
            raise SettingsError(f"settings for {method!r}: it has no settings of its own (Method.knobs)")
        hints = _hints(method)
        unknown = sorted(set(fields) - set(hints))
        if unknown:
            raise SettingsError(f"{method}: unknown setting(s) {unknown}; valid: {', '.join(hints)}")
        try:
            out[method] = methods.get(method).knobs(**{k: coerce(hints[k], v, f"{method}.{k}")
                                                       for k, v in fields.items()})
        except SettingsError:
            raise
        except (TypeError, ValueError) as e:
            raise SettingsError(str(e) if str(e).startswith(method) else f"{method}: {e}") from None
    return out


def to_json(records: Mapping[str, Any]) -> dict[str, dict]:
    """`{method: {field: value}}` of every field of each record (lists for tuples), for results.json."""
    def plain(v):
        return [plain(x) for x in v] if isinstance(v, (tuple, list)) else v
    return {m: {k: plain(v) for k, v in dataclasses.asdict(r).items()} for m, r in sorted(records.items())}


def from_json(block: Mapping[str, Mapping[str, Any]] | None) -> dict[str, Any]:
    """The records a results file's `settings.knobs` holds (`build`); a method no longer registered is kept out
    of the sweep rather than refused: its runs are read, not trained."""
    return build({m: v for m, v in (block or {}).items() if owns(m)})


def differences(records: Mapping[str, Any]) -> Iterable[str]:
    """`METHOD.FIELD=VALUE` for each field of `records` that differs from its method's default."""
    for method, record in sorted(records.items()):
        default = methods.get(method).knobs()
        for f in dataclasses.fields(record):
            if getattr(record, f.name) != getattr(default, f.name):
                yield format_set(method, f.name, getattr(record, f.name))
