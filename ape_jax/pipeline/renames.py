"""Names that changed, one place: the recipes' former names (`FORMER_RECIPES`; the protocols' and experts' are
`ape_jax.tasks.FORMER_PROTOCOLS` and `FORMER_EXPERTS`), a protocol named on the command line as it is called now
(`current_protocol`), and the one-line notice a former name gets, once per process (`notice_renamed`;
`docs/design.md`, "Words"). A results file or checkpoint recording a former name reads as today's silently
(`older_files`)."""

from __future__ import annotations

import sys
from collections.abc import Mapping

from ape_jax import tasks

# the FCA code's recipe was named `fca` and PALR's `palr`, as the methods are (one name per thing)
FORMER_RECIPES: Mapping[str, str] = {"fca": "bn-mlp", "palr": "mlp-b1024"}

_noticed: set[tuple[str, str]] = set()


def current_protocol(name: str | None) -> str | None:
    """A protocol named on the command line, as it is called now (`tasks.FORMER_PROTOCOLS`), with the notice."""
    new = tasks.FORMER_PROTOCOLS.get(name or "")
    if new:
        notice_renamed("protocol", name, new)
    return new or name


def notice_renamed(kind: str, old: str, new: str) -> None:
    """Says once per process, on stderr, that `kind` `old` is now called `new` (`docs/design.md`, "Words")."""
    if (kind, old) not in _noticed:
        _noticed.add((kind, old))
        extra = "" if kind != "protocol.expert" else (
            f" (an expert imported as {old!r} before is found as {new!r} once imported again: "
            f"python -m experiments.import_expert PATH --env ENV --name {new})")
        print(f"notice: {kind} {old!r} is now {new!r}; the old name keeps working{extra}", file=sys.stderr)
