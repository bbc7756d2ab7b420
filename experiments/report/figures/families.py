"""Which groups a figure draws together: one figure per question, not one panel per group in a single picture.

A *family* is a set of groups that answer one question, chosen by their setting (never by their results):

- `default`: the state tasks with the shipped experts under the paper's protocol and recipe (split by rows, the
  FCA code's network), at every budget they ran: does anything beat BC-OH where the paper says it should?
- `copycat`: where copying is expected (`analysis.ranking.is_copycat_cell`: an expert of FCA's kind, raw labels,
  the previous action in view);
- `first`: the paper's protocol family as this project first ran it (the `mlp` recipe, split by whole episodes;
  other frame skips and training-set sizes);
- `variants`: the paper's protocol family split by rows under another recipe, history, expert, frame skip or
  training-set size;
- `images`: image observations, and tasks that are not MuJoCo's (the driving sandbox);
- `other`: every other protocol (Brax's own frame skip and episodes).

`families` sorts groups into them, `panel_title` names a group inside its family's figure (the family's heading
says what the groups share, so the panel names only what sets it apart).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple

from ape_jax import tasks
from experiments.report.analysis import STATE, MUJOCO, Group, in_state_family
from experiments.report.analysis.groups import other_setting
from experiments.report.analysis.ranking import is_copycat_cell
from experiments.report.analysis.regime import cell_title

# (name, heading) per family, in the order the report shows them.
FAMILIES = (("default", "The default tasks: the shipped experts under the paper's protocol and recipe"),
            ("copycat", "Where copying is expected: an expert of FCA's kind, raw labels, or the previous action in "
                        "view"),
            ("first", "The paper's protocol as first run here: the mlp recipe, split by whole episodes"),
            ("variants", "The paper's protocol split by rows under another recipe, history, expert, frame skip or "
                         "data size"),
            ("images", "Image observations and the driving sandbox"),
            ("other", "Other protocols: Brax's own frame skip and episodes"))


class Family(NamedTuple):
    """One family of groups: its `name` (a figure file's suffix, `returns-default.png`), its heading (the
    figure's title) and its groups in the order they were given."""

    name: str
    heading: str
    groups: tuple[Group, ...]


def family_of(m: Group) -> str:
    """The family (`FAMILIES`) group `m` belongs to, by its setting."""
    p = m.protocol
    if is_copycat_cell(m):
        return "copycat"
    if m.env not in MUJOCO or m.obs != "pos":
        return "images"
    if (p.get("variant_of") == STATE and p.get("recipe") == "bn-mlp" and p.get("split") == "rows"
            and not other_setting(p)):
        return "default"
    if in_state_family(p.get("variant_of") or p["name"]):
        return "variants" if p.get("variant_of") else "first"
    return "other"


def families(groups: Iterable[Group]) -> list[Family]:
    """`groups` sorted into their families (`family_of`), in `FAMILIES` order, each keeping the order given (`default`
    by the iterations trained first, so each budget's tasks sit side by side); a family without groups is left
    out."""
    found: dict[str, list[Group]] = {}
    for m in groups:
        found.setdefault(family_of(m), []).append(m)
    if "default" in found:
        found["default"].sort(key=lambda g: int(g.sources[0].config["iterations"]))
    return [Family(name, heading, tuple(found[name])) for name, heading in FAMILIES if name in found]


def panel_title(m: Group, family: Family) -> str:
    """Group `m`'s panel title in `family`'s figure: in `default` the task and the iterations it trained for
    (`"Hopper, 300,000 iterations"`), in `copycat` the ranking's cell name with the iterations
    (`"Hopper (FCA's expert, raw labels), 30,000 iterations"`), elsewhere the group's full title. Where two
    groups of the family would share a short title, the full one."""
    def short(g: Group) -> str:
        its = f"{int(g.sources[0].config['iterations']):,} iterations"
        if family.name == "default":
            return f"{tasks.get(g.env).title}, {its}"
        return f"{cell_title(g)}, {its}" if family.name == "copycat" else g.title

    mine = short(m)
    return mine if sum(short(g) == mine for g in family.groups) == 1 else m.title
