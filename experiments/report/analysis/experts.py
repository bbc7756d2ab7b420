"""Who made a group's demonstrations, as the report reads it from a results file: the demonstrator's record
(`demonstrator`), how group names and titles name an expert that is not the task's own (`expert_part`,
`expert_words`), whether the labels are raw (`raw_labels`), and whether two files' expert records describe one
expert (`same_expert`)."""

from __future__ import annotations

from ape_jax.pipeline import results as results_lib


def demonstrator(res: results_lib.Results) -> dict | None:
    """Who made a file's demonstrations, as the file records it: the collected data's expert
    (`config.data.settings.expert`: `kind` `checkpoint` with its card's SHA-256, `imported` with its file's SHA-256,
    format and origin, or `rule-based`), else a dataset's (`expert.demonstrator`); None where neither is recorded
    (files from before the record)."""
    data = ((res.config.get("data") or {}).get("settings") or {}).get("expert")
    found = data if isinstance(data, dict) else (res.expert or {}).get("demonstrator")
    return found if isinstance(found, dict) else None


def expert_part(res: results_lib.Results, protocol: dict) -> str | None:
    """How a group name names a file's expert where it is not the task's own (None where it is): a shipped variant
    by its name (`protocol.expert`: `ppo`, `rough`), an imported one (`experiments.import_expert`) by its name and
    the first 8 hex digits of its file's SHA-256 (`cs294-56145a42`), so two files imported under one name never
    share a group."""
    found, name = demonstrator(res) or {}, protocol.get("expert")
    if found.get("kind") != "imported":
        return name
    name = name or found.get("variant") or found.get("name") or "imported"
    sha = found.get("sha256")
    return f"{name}-{sha[:8]}" if isinstance(sha, str) and sha else name


def raw_labels(protocol: dict) -> bool:
    """Whether the demonstrations' labels are the expert's output as it gave it (`protocol.labels` `raw`), not
    clipped to the action range (`clipped`, the default, which files before the field all were)."""
    return protocol.get("labels") == "raw"


def expert_words(p: dict) -> str | None:
    """How titles name a group's expert and labels where either is not the default: `"ppo"` (a shipped variant),
    `"cs294 (imported, SHA-256 56145a42…)"`, with `", labels raw"` where the labels are the expert's own output; None
    for the task's own expert with clipped labels. `p` is a group's protocol (`Group.protocol`, which carries an
    imported expert's `expert_sha256`)."""
    name = p.get("expert")
    if name is None and p.get("expert_sha256"):
        name = "imported"
    if name is not None and p.get("expert_sha256"):
        name += f" (imported, SHA-256 {p['expert_sha256'][:8]}…)"
    if raw_labels(p):
        name = ("the task's own" if name is None else name) + ", labels raw"
    return name


def same_expert(a: object, b: object, rel: float = 1e-3) -> bool:
    """Whether two files' `expert` records describe one expert: the same fields, text equal, numbers within `rel`
    of the larger's size (and within `rel` of each other near 0): one deterministic expert measured by other code
    or on another CPU differs in float rounding, e.g. a return sd of 2.9826 against 2.9838."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_expert(a[k], b[k], rel) for k in a)
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return abs(a - b) <= rel * max(abs(a), abs(b), 1.0)
    return a == b
