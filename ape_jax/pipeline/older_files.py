"""Results files written by older versions, read as today's (`Results.from_json` calls both, on its own copy):
a schema 1/2 file's flat `config` as the three records (`legacy_settings`), and the former names of the protocol,
the recipe and the imported expert (`current_names`: `docs/design.md`, "Words")."""

from __future__ import annotations

import dataclasses

from ape_jax import tasks
from ape_jax.pipeline.presets import FORMER_RECIPES


# A schema 1/2 `config`'s fields, by the record they belong to now.
CONFIG_FIELDS = {"budget": ("iterations", "seeds", "eval_episodes", "ape_steps", "chunk"),
                 "recipe": ("lr", "batch_size", "ape_normalization", "step_grid", "softmax_grid", "encoder"),
                 "protocol": ("history", "eval_steps", "val_frac", "image_size", "episodes")}


def legacy_settings(obj: dict) -> dict:
    """The three records of a schema 1/2 file, from its flat `config`: the `mlp` recipe (with the file's own
    learning rate, batch and grids) and its protocol split by episode, as every sweep before schema 3 ran."""
    config, name = obj["config"], (obj.get("protocol") or {}).get("name") or "brax"
    base = dataclasses.asdict(tasks.PROTOCOLS[name]) if name in tasks.PROTOCOLS else {"name": name}
    base = {k: list(v) if isinstance(v, tuple) else v for k, v in base.items()}  # as JSON holds them (`reveal`)
    out = {"protocol": {**base, "split": "episodes"}, "budget": {}, "recipe": {"name": "mlp"}}
    for section, keys in CONFIG_FIELDS.items():
        out[section].update({k: config[k] for k in keys if config.get(k) is not None})
    return out


def current_names(obj: dict) -> None:
    """Renames in place what a file from before each thing had one name calls by a former name (the protocol,
    its reference, the expert: `tasks.FORMER_PROTOCOLS`, `FORMER_EXPERTS`; the recipe: `presets.FORMER_RECIPES`),
    so every reader sees one name for one thing; the file on disk is left as written."""
    for holder in (obj, obj.get("settings") or {}):
        if isinstance(holder.get("protocol"), dict):
            holder["protocol"] = tasks.current_names(holder["protocol"])
    recipe = (obj.get("settings") or {}).get("recipe")
    if isinstance(recipe, dict) and recipe.get("name") in FORMER_RECIPES:
        recipe["name"] = FORMER_RECIPES[recipe["name"]]
    data = obj["config"].get("data")
    if isinstance(data, dict) and isinstance((data.get("settings") or {}).get("expert"), dict):
        data["settings"]["expert"] = tasks.current_expert(data["settings"]["expert"])
    if obj["config"].get("recipe") in FORMER_RECIPES:
        obj["config"]["recipe"] = FORMER_RECIPES[obj["config"]["recipe"]]


def task_versions(obj: dict) -> None:
    """A file of a task with versions (ToyTown's `task_version`) that records none was written before versions were
    recorded, so it ran the first: its `protocol` and `settings.protocol` say so (1), in place, and a replay or a
    re-evaluation rebuilds that task, never today's. Files of other tasks are left as they are."""
    from ape_jax.pipeline.setup import current_task_version

    if current_task_version(obj.get("env", "")) is None:
        return
    for holder in (obj, obj.get("settings") or {}):
        if isinstance(holder.get("protocol"), dict) and holder["protocol"].get("task_version") is None:
            holder["protocol"]["task_version"] = 1
