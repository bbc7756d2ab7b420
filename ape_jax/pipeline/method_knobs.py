"""Methods' own settings on the command line and in results: `--set METHOD.KNOB=VALUE`.

    knobs = parse_sets(["ptp.weights=0.5,1", "ptp.past=3"])   # {"ptp": {"weights": (0.5, 1.0), "past": 3}}
    records = build(knobs)                                    # {"ptp": PtpKnobs(weights=(0.5, 1.0), past=3)}
    to_json(records)                                          # results.json's `settings.knobs`

A method that declares a `Method.knobs` record (a frozen dataclass in its own module: its fields typed, its
defaults the authors', its values checked in `__post_init__`) owns those settings: the sweep takes them as
`--set METHOD.KNOB=VALUE`, parsed by the field's type hint as every `--set` is (`ape_jax.pipeline.hints`),
records those that differ from the method's defaults in results.json beside the three records (`settings.knobs`;
a file whose methods all ran at their defaults has none), and hands them to the method's grid and learner
(`GridContext.knobs`, `ctx.knobs_of(name)`). Nothing else lists a method's knobs.

Before the methods owned their settings, the recipe held them (`recipe.step_grid`, `recipe.fca_alphas`, ...):
`LEGACY` maps each old name to the knobs it is now. `--set recipe.OLD=...` still works, with a one-line notice,
and a results file or checkpoint that records the old fields reads as the records they mean, so its settings,
fingerprint and replay are what they were.
"""

from __future__ import annotations

import dataclasses
import sys
import typing
from collections.abc import Iterable, Mapping
from typing import Any


from ape_jax import methods
from ape_jax.weighting import SoftmaxKnobs, StepKnobs
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


def from_json(block: Mapping[str, Mapping[str, Any]] | None,
              legacy_values: Mapping[str, Mapping[str, Any]] = {}) -> dict[str, Any]:  # noqa: B006 - read only
    """The records a results file's `settings.knobs` holds (`build`), over what its recipe's old method fields
    mean (`from_legacy`); a method no longer registered is kept out of the sweep rather than refused: its runs are
    read, not trained."""
    values: dict[str, dict[str, Any]] = {}
    merge(values, legacy_values)
    merge(values, {m: v for m, v in (block or {}).items() if owns(m)})
    return build({m: v for m, v in values.items() if owns(m)})


def differences(records: Mapping[str, Any], base: Mapping[str, Any] = {}) -> Iterable[str]:  # noqa: B006
    """`METHOD.FIELD=VALUE` for each field of `records` that differs from `base`'s (a method `base` lacks: its
    defaults), and each of `base`'s that `records` has at its default."""
    for method in sorted(set(records) | set(base)):
        record, default = methods.knobs_of(method, records), methods.knobs_of(method, base)
        for f in dataclasses.fields(record):
            if getattr(record, f.name) != getattr(default, f.name):
                yield format_set(method, f.name, getattr(record, f.name))


# -- the recipe's method fields before the methods owned them ----------------------------------------------------

# old recipe field -> (the methods it is a knob of: names, or a record type every method with that record shares;
# the knob's name; whether an empty value meant the method's default rather than an empty grid)
LEGACY: Mapping[str, tuple[Any, str, bool]] = {
    "step_grid": (StepKnobs, "grid", False), "softmax_grid": (SoftmaxKnobs, "taus", False),
    "ape_normalization": (SoftmaxKnobs, "ape_normalization", False),
    "fca_alphas": (("fca", "fca-ib"), "alphas", False), "fca_adversary_lr": (("fca", "fca-ib"), "adversary_lr", False),
    "ib_weights": (("fca-ib",), "weights", True),
    "rap_weights": (("rap",), "weights", True), "rap_widths": (("rap",), "widths", True),
    "palr_weights": (("palr",), "weights", True), "palr_bandwidths": (("palr",), "bandwidths", True),
    "palr_rows": (("palr",), "rows", False),
    "mine_weights": (("mine",), "weights", True), "mine_steps": (("mine",), "steps", False),
    "mine_rows": (("mine",), "rows", False),
}
_noticed: set[str] = set()


def _targets(field: str) -> list[str]:
    owners = LEGACY[field][0]
    return methods.sharing(owners) if isinstance(owners, type) else [m for m in owners if owns(m)]


def legacy(field: str, value: Any) -> dict[str, dict[str, Any]]:
    """Old recipe field `field` at `value` as `{method: {knob: value}}` (nothing where an empty value meant the
    methods' defaults)."""
    _, knob, empty_is_default = LEGACY[field]
    if empty_is_default and isinstance(value, (tuple, list)) and not value:
        return {}
    return {m: {knob: value} for m in _targets(field)}


def parse_legacy(field: str, text: str, item: str) -> Any:
    """The value of `--set recipe.FIELD=TEXT` for an old method field, parsed as the knob it is now."""
    return parse_set(_targets(field)[0], LEGACY[field][1], text, item)


def notice(field: str) -> None:
    """Says once per process, on stderr, what an old `recipe.FIELD` is now called."""
    if field not in _noticed:
        _noticed.add(field)
        knob = LEGACY[field][1]
        now = ", ".join(f"{m}.{knob}" for m in _targets(field))
        print(f"notice: recipe.{field} is now {now} (--set METHOD.KNOB=VALUE); the old name keeps working",
              file=sys.stderr)


def merge(into: dict[str, dict[str, Any]], values: Mapping[str, Mapping[str, Any]]) -> None:
    """Adds `{method: {knob: value}}` to `into`, later values replacing earlier ones."""
    for method, fields in values.items():
        into.setdefault(method, {}).update(fields)


def from_legacy(recipe: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """`{method: {knob: value}}` that a recorded recipe's old method fields mean (a file from before the methods
    owned their settings)."""
    out: dict[str, dict[str, Any]] = {}
    for field in LEGACY:
        if recipe.get(field) is not None:
            merge(out, legacy(field, recipe[field]))
    return out


def first_only(records: Mapping[str, Any]) -> dict[str, Any]:
    """Every knob-owning method's record (the given one, else its defaults) with each grid axis cut to its first
    setting: a smoke run's."""
    out = {}
    for name in methods.names():
        record = methods.get(name).knobs
        if record is None:
            continue
        r = records.get(name) or record()
        out[name] = dataclasses.replace(r, **{f.name: getattr(r, f.name)[:1] for f in dataclasses.fields(r)
                                              if isinstance(getattr(r, f.name), tuple)})
    return out


def without_defaults(records: Mapping[str, Any]) -> dict[str, Any]:
    """`records` less those equal to their method's defaults (what a sweep's settings keep and record)."""
    return {m: r for m, r in sorted(records.items()) if not owns(m) or r != methods.get(m).knobs()}
