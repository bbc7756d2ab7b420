"""Results files loaded and merged into groups: one task, observation mode, protocol and budget each.

- `load` reads one results file (`ape_jax.pipeline.results.load`, the one validator), refusing `--smoke` runs;
- `merge` joins them per `Key(env, obs, protocol, budget)`: results of one task under two protocols (the paper's
  `mujoco-state`, Brax's own `brax`) are different experiments, on different scales, and never mix;
- `ordered`, `group_title`, `file_stem`, `groups_of`, `protocols_of`: the groups in report order, and how
  tables and figure files name them.

Protocols: a file's `protocol["name"]`; schema 1 files record none and ran Brax's own settings, so they are
`brax`. The *mujoco-state family* is `mujoco-state` (the paper's MuJoCo-State setting, frame skip 1) and every protocol
named `mujoco-state-...` (the same setting at another frame skip or training-set size, e.g. `mujoco-state-fs4`), told
apart by the `frame_skip` and `train_transitions` they record.

Experts and labels: a file whose demonstrations came from another expert than the task's own, or stored the
expert's labels raw (`protocol.labels`), is a group of its own (`variant_name`): a shipped variant by its name
(`protocol.expert`), an imported expert by its name and its file's SHA-256 (`demonstrator`, `expert_part`), raw
labels apart from clipped ones; titles say which (`expert_words`). A file judged by its return that records no
expert references cannot be normalised, and is refused (`check_references`).
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from typing import NamedTuple
from collections.abc import Mapping, Sequence

from ape_jax import tasks
from ape_jax.pipeline import results as results_lib
from ape_jax.pipeline.presets import SettingsError
from ape_jax.pipeline.setup import current_task_version
from experiments.report.analysis.encoders import encoder_stem, encoder_words, perception_of
from experiments.report.analysis.experts import (demonstrator, expert_part, expert_words, raw_labels,
                                                same_expert)


# The state tables' tasks: those with an expert that are judged by their return (the MuJoCo tasks).
MUJOCO = tuple(t for t in tasks.sweepable() if tasks.get(t).metric == "return")


class ReportError(results_lib.ResultsError):
    """A results file that cannot be read or merged (one line, naming the file)."""


@dataclasses.dataclass
class Source(results_lib.Results):
    """One results file as the report read it: its `Results`, and where it came from."""

    path: str = ""


def load(path: str | pathlib.Path) -> Source:
    """Reads and validates one results file (`ReportError`, one line naming it, if it cannot be used)."""
    from experiments._cli import unreadable

    if pathlib.Path(path).exists() and (why := unreadable(path, "a results file")):   # a folder: said as such
        raise ReportError(why)
    try:
        res = results_lib.load(path)
    except results_lib.ResultsError as e:
        raise ReportError(str(e)) from None
    if not res.runs:   # its summary alone would give numbers no run backs
        raise ReportError(f"{path}: the file has no runs (its \"runs\" list is empty), so it has no numbers to "
                          "report; give a results.json that experiments.sweep finished")
    if res.config.get("smoke"):
        raise ReportError(f"{path}: a --smoke run (its amounts shrunk to seconds, its numbers mean nothing); "
                          f"the report takes real runs only")
    return Source(**{f.name: getattr(res, f.name) for f in dataclasses.fields(results_lib.Results)}, path=str(path))


def check_references(res: results_lib.Results) -> None:
    """Refuses (`ReportError`, one line naming the file and how to add them) a file judged by its return that records
    no expert reference returns (`expert.return_mean` or `random_return_mean` null: a `--dataset` sweep whose
    dataset gave none): the report's and `experiments.compare`'s tables are in % of expert, which it cannot give."""
    if main_metric(res) != "return" or all(isinstance((res.expert or {}).get(k), (int, float))
                                           for k in ("return_mean", "random_return_mean")):
        return
    where = getattr(res, "path", "") or f"a {res.env} ({res.obs}) results file"
    dataset = ((res.config.get("data") or {}).get("settings") or {}).get("dataset")
    raise ReportError(f"{where}: records no expert reference returns (expert.return_mean is null), so it has no "
                      "% of expert for the normalised tables; add the references to "
                      + (f"its dataset {dataset}" if dataset else "its dataset")
                      + " (\"references\": {\"return_mean\": R_EXPERT, \"random_return_mean\": R_RANDOM} in its "
                      ".json, or ref_max_score and ref_min_score in its metadata.json) or name its expert with --set "
                      "protocol.expert=NAME, and sweep again")


def main_metric(res: results_lib.Results) -> str:
    """What a results file is judged by: the metric it records, else its task's (schema 1 records none)."""
    return res.main_metric if "metric" in res.config else tasks.get(res.env).metric


BRAX, STATE = "brax", tasks.STATE  # the protocol of files that record none; the paper's MuJoCo-State protocol


# mujoco-state's training transitions (its protocol record's): the frame-skip rows of the map all have it.
STATE_TRAIN = tasks.PROTOCOLS[STATE].train_transitions


class Key(NamedTuple):
    """A merged group of results: one task, one observation mode, one protocol (its name), one training budget.

    `budget` is None for files that trained their preset's iterations, else their iterations (a run with
    `--iterations`, e.g. the long runs that ask whether more training changes a verdict): results at another
    budget are another experiment, shown apart and compared in "Training longer" (`longer_runs`).
    `version` is the task version a task with versions ran (ToyTown's `task_version`; a file that records none ran
    version 1), None for other tasks: two versions show other things, so their results are never merged.
    `perception` is the first 12 hexadecimal digits of the SHA-256 of the encoder the frames were seen through
    (`recipe.perception_sha256`), None for policies that learn from pixels (or states): two encoders never merge.
    """

    env: str
    obs: str
    protocol: str
    budget: int | None = None
    version: int | None = None
    perception: str | None = None


@dataclasses.dataclass(frozen=True)
class Group:
    """The merged results of one `Key` (`merge`): every file of one task, observation mode, protocol and budget.

    Attributes:
      env, obs: the task and its observation mode.
      protocol: the files' protocol settings, `name` always set (`brax` for schema 1 files; a variant's group name,
        with `variant_of` and `recipe`, for a variant: `variant_name`).
      budget: `Key.budget`: None for the preset's iterations, else the iterations.
      expert: the expert's record (`return_mean`, `return_std`, `random_return_mean`), the same in every file.
      demonstrator: who made the demonstrations (`demonstrator`: kind, SHA-256, origin), as the first file records
        it; None where it does not.
      summary: every file's summary rows (one per configuration), in file order.
      runs: every file's runs (one per configuration and seed), in file order.
      sources: the files, in the order given (without the rows set aside).
      set_aside: `(file, method)` of rows a file trained only for another of its methods to read (`read_only`:
        priming's BC-SO) where another file of the group trained the same configuration as a row of its own: that
        file's rows stand, these are left out (the same configuration trained again).
      methods: what the files record of their methods (label, role, online), the first file naming one wins.
      metric: the main metric (`"return"`, or a rate: `is_rate`).
      task_metrics: the task's own per-episode metrics (the task-metrics table's columns).
      shows_protocol: whether titles name the protocol: unless it is `brax` and the only protocol of this task and
        observation mode.
      title: how tables name the group (`group_title`, with the budget where it is not the preset's).
    """

    env: str
    obs: str
    protocol: dict
    budget: int | None
    expert: dict
    demonstrator: dict | None
    summary: list[dict]
    runs: list[dict]
    sources: list[Source]
    set_aside: list[tuple[str, str]]
    methods: dict[str, dict]
    metric: str
    task_metrics: tuple[str, ...]
    shows_protocol: bool
    title: str


Merged = Mapping[Key, Group]  # `merge`'s result: the groups by key


def trained_its_preset(res: results_lib.Results) -> bool:
    """Whether `res` trained the iterations its preset gave (not changed by `--iterations` or `--set`).

    A file says so itself (`config["preset_iterations"]`, what the preset gave before `--iterations`/`--set`);
    a file from before that record is compared with today's preset of its name (False for a preset this code
    lacks)."""
    from ape_jax.pipeline.presets import BUDGETS, resolve

    iterations, recorded = res.config.get("iterations"), res.config.get("preset_iterations")
    if isinstance(recorded, int):
        return iterations == recorded
    return res.preset in BUDGETS and iterations == resolve(res.env, res.obs, preset=res.preset).budget.iterations


def budget_of(res: results_lib.Results) -> int | None:
    """`res`'s iterations where it did not train its preset's (None: the preset's, or a file that records none).

    A `paper` run is the `default` experiment trained longer (300k iterations where `default` trains 30k): its
    iterations always, a group of its own beside the `default` group, never merged into it. A file from before
    the record of its preset's iterations, of a preset this code lacks, counts as its preset's.
    """
    from ape_jax.pipeline.presets import BUDGETS

    iterations = res.config.get("iterations")
    if not isinstance(iterations, int):
        return None
    if res.preset == "paper":
        return iterations
    if "preset_iterations" not in res.config and res.preset not in BUDGETS:
        return None
    return None if trained_its_preset(res) else iterations


def in_state_family(name: str) -> bool:
    """Whether group `name` (`Key.protocol`, a protocol's name or a variant's, `variant_name`) reads with the paper's
    protocol family: `mujoco-state` itself, or any group of another member of `ape_jax.tasks.FAMILIES["mujoco-state"]`
    (other frame skips, other training-set sizes), whatever its split or recipe. The paper's own protocol under another
    split or recipe (`mujoco-state.rows.bn-mlp`) is a group of its own, which the recipe section compares."""
    base = name.split(".", 1)[0]
    return name == STATE or (base != STATE and tasks.protocol_family(base) == STATE)


def protocol_of(res: results_lib.Results, where: str = "") -> dict:
    """The protocol `res` ran under, its `name` filled in: `brax` for a file that records none (schema 1).

    Raises:
      ReportError: a protocol whose name is not a non-empty string, or whose `frame_skip` is not a positive int.
    """
    p = {**(res.protocol or {})}
    name = p.setdefault("name", BRAX)
    if not isinstance(name, str) or not name:
        raise ReportError(f"{where}: protocol field 'name' must be a non-empty string, got {name!r:.80}")
    skip = p.get("frame_skip")
    if skip is not None and not (isinstance(skip, int) and not isinstance(skip, bool) and skip >= 1):
        raise ReportError(f"{where}: protocol field 'frame_skip' must be an int >= 1 or null, got {skip!r:.80}")
    return p


# The MuJoCo tasks' first `default` image preset (the small conv encoder, 25 demonstrations, 5,000 iterations,
# softmax τ 10; CHANGELOG.md): its files are a setting of their own, never merged with the current `default`.
FIRST_IMAGE_PRESET, FIRST_IMAGE_ITERATIONS = "first image preset", 5_000


def former_preset(res: results_lib.Results) -> str | None:
    """The name of the retired preset `res` ran, else None. A MuJoCo image file of preset `default` with the small
    conv encoder whose preset gave 5,000 iterations (`config.preset_iterations`; files from before that record:
    all of them then) ran the first image preset."""
    if not (res.obs == "image" and res.env in MUJOCO and res.preset == "default"
            and res.config.get("preset_iterations", FIRST_IMAGE_ITERATIONS) == FIRST_IMAGE_ITERATIONS):
        return None
    encoder = ((res.settings or {}).get("recipe") or {}).get("encoder") or res.config.get("encoder") or "small"
    return FIRST_IMAGE_PRESET if encoder == "small" else None


def variant_name(res: results_lib.Results, protocol: dict) -> str:
    """The group name of a file's setting: its protocol's name for files split by episode with the `mlp` recipe (every
    file before results schema 3), else `NAME.SPLIT.RECIPE` (e.g. `mujoco-state.rows.bn-mlp`; `.h<H>` for another
    history, `.stride<K>` for a history's frames K steps apart, `.<expert>` for another expert (`expert_part`: `.ppo`,
    `.cs294-56145a42`), `.raw` for raw labels, `.prev` with the previous action in view), a group of its own: the
    recipe section (`recipe_groups`, `recipe_rows`) compares them, and they never join the copycat map or the
    whole-episode tables. A retired preset's files
    (`former_preset`) are `NAME.first`, a group of their own too."""
    if former_preset(res) is not None:
        return f"{protocol['name']}.first"
    split, recipe = protocol.get("split") or "episodes", res.recipe_name
    history, expert, prev = other_history(protocol), expert_part(res, protocol), bool(protocol.get("prev_action"))
    raw, stride = raw_labels(protocol), protocol.get("history_stride") or 1
    if (split, recipe, history, expert, raw, prev, stride) == ("episodes", "mlp", None, None, False, False, 1):
        return protocol["name"]
    return (f"{protocol['name']}.{split}.{recipe}" + ("" if history is None else f".h{history}")
            + ("" if stride == 1 else f".stride{stride}")
            + ("" if expert is None else f".{expert}") + (".raw" if raw else "") + (".prev" if prev else ""))


def other_setting(protocol: dict) -> bool:
    """Whether a variant changes more than the split and the recipe: another history or another expert, raw labels,
    the previous action in view (`protocol.prev_action`), or a retired preset (such groups stay out of the recipe
    table and the paper-budget table, and are settings of their own in the map)."""
    return (other_history(protocol) is not None or protocol.get("expert") is not None or raw_labels(protocol)
            or bool(protocol.get("prev_action")) or "preset" in protocol or (protocol.get("history_stride") or 1) > 1)


def other_history(protocol: dict) -> int | None:
    """The protocol's history where it differs from its named protocol's (`--set protocol.history=7`), else None
    (the named protocol's, or a protocol this code does not know)."""
    named = tasks.PROTOCOLS.get(protocol.get("variant_of") or protocol.get("name"))
    history = protocol.get("history")
    return history if named is not None and isinstance(history, int) and history != named.history else None


def protocol_words(p: dict) -> str:
    """How titles name a protocol: `"mujoco-state"`, `"mujoco-state, frame skip 2"`, `"mujoco-state, 80,000 training
    transitions"` (the rest of the mujoco-state family, by what differs from it), `"mujoco-state, split by rows, recipe
    bn-mlp"` (a variant, `variant_name`), else its name."""
    name = p["name"]
    if p.get("preset"):
        return f"{p['variant_of']}, {p['preset']}"
    if p.get("variant_of"):
        history = other_history(p)
        return (f"{p['variant_of']}, split by {p.get('split')}, recipe {p.get('recipe')}"
                + ("" if history is None else f", history {history}")
                + ("" if (p.get("history_stride") or 1) == 1 else f", frames {p['history_stride']} steps apart")
                + ("" if (words := expert_words(p)) is None else f", expert {words}")
                + (", previous action in view" if p.get("prev_action") else ""))
    if not in_state_family(name) or name == STATE:
        return name
    differs = ([f"frame skip {p['frame_skip']}"] if p.get("frame_skip") not in (None, 1) else []) + \
        ([f"{p['train_transitions']:,} training transitions"]
         if p.get("train_transitions") not in (None, STATE_TRAIN) else [])
    return ", ".join([STATE, *differs]) if differs else name


def _where(r: results_lib.Results) -> str:
    """How messages name a file: its path, else its task."""
    return getattr(r, "path", "") or f"a {r.env} ({r.obs}) results file"


def _key(r: results_lib.Results) -> tuple[dict, Key]:
    """A file's protocol as its group records it (a variant's: named by `variant_name`, with `variant_of`, the
    recipe, a former preset and an imported expert's SHA-256) and its group's `Key`."""
    protocol = protocol_of(r, _where(r))
    if (encoder := perception_of(r)) is not None:
        protocol = {**protocol, "perception": encoder}
    name = variant_name(r, protocol)
    found = demonstrator(r) or {}
    if name != protocol["name"]:
        protocol = {**protocol, "name": name, "variant_of": protocol["name"], "recipe": r.recipe_name,
                    **({"preset": former} if (former := former_preset(r)) else {}),
                    **({"expert_sha256": found["sha256"]} if found.get("kind") == "imported"
                       and found.get("sha256") else {})}
    return protocol, Key(r.env, r.obs, name, None if former_preset(r) else budget_of(r), protocol.get("task_version"),
                         encoder)


def read_only(res: results_lib.Results) -> set[str]:
    """The methods a file trained for another of its methods to read (`Method.reads`: priming's BC-SO, the prime
    it reads), under the file's own settings; empty for files this code cannot resolve."""
    from ape_jax import methods as methods_lib

    try:
        knobs = res.records().knobs
    except (SettingsError, TypeError, ValueError):
        return set()
    names = {row["method"] for row in res.summary}
    return {read for m in names if m in methods_lib.names() and (read := methods_lib.read_by(m, knobs))} & names


def merge(files: Sequence[results_lib.Results]) -> dict[Key, Group]:
    """Results per `Key(env, obs, protocol name, budget)`: summary rows and runs of all files, with the files they
    came from, as a `Group` each.

    One configuration's seeds may come from several files of one sweep split by seeds (`--set
    budget.first_seed=K`, the same settings otherwise): its runs are joined. Every summary row is computed from
    its runs (`results.summarize`), its std the sample sd over seeds (ddof 1; None for one seed).

    Raises:
      ReportError: the same configuration and seed in two files of one group, or the same configuration in two
        files with other settings; files of one group with different experts (`same_expert`, and the demonstrator
        where both record it) or different protocol settings, or a malformed protocol.
    """
    merged: dict[Key, dict] = {}   # the groups' fields, gathered file by file
    keyed = [(r, *_key(r), read_only(r)) for r in files]
    primary: dict[Key, set] = {}   # per group, the configurations some file trained for their own sake
    for r, _, key, reads in keyed:
        primary.setdefault(key, set()).update(config_key(row) for row in r.summary if row["method"] not in reads)
    for r, protocol, key, reads in keyed:
        where = _where(r)
        aside = {config_key(row) for row in r.summary if row["method"] in reads} & primary[key]
        if aside:   # another file of the group trained them as rows of their own: theirs stand
            r = dataclasses.replace(r, summary=[row for row in r.summary if config_key(row) not in aside],
                                    runs=[run for run in r.runs if config_key(run) not in aside])
        m = merged.setdefault(key, {"env": r.env, "obs": r.obs, "protocol": protocol, "budget": key.budget,
                                    "expert": r.expert, "demonstrator": demonstrator(r),
                                    "summary": [], "runs": [], "sources": [], "set_aside": [], "methods": {},
                                    "metric": main_metric(r),
                                    "task_metrics": tuple(r.config.get("task_metrics", tasks.get(r.env).metrics))})
        group = f"{r.env} ({r.obs}, protocol {key.protocol}" + (f", {key.budget:,} iterations)" if key.budget else ")")
        if not same_expert(m["expert"], r.expert) or (m["demonstrator"] and demonstrator(r)
                                                       and m["demonstrator"] != demonstrator(r)):
            raise ReportError(f"{where}: its expert differs from another {group} results file's")
        differ = [k for k in protocol.keys() & m["protocol"].keys()
                  if protocol[k] is not None and m["protocol"][k] is not None and protocol[k] != m["protocol"][k]]
        if differ:
            raise ReportError(f"{where}: its protocol differs from another {group} results file's (" + ", ".join(
                f"{k} {protocol[k]!r} vs {m['protocol'][k]!r}" for k in sorted(differ)) + ")")
        seen = {config_key(row) for row in m["summary"]}
        for row in r.summary:
            if config_key(row) in seen:
                _check_seed_split(r, row, m, where, group)
        m["summary"] += [row for row in r.summary if config_key(row) not in seen]
        m["runs"] += r.runs
        m["sources"].append(r)
        m["set_aside"] += [(where, method) for method, _ in sorted(aside)]
        m["methods"] = {**r.methods, **m["methods"]}
        m["protocol"] = {**protocol, **{k: v for k, v in m["protocol"].items() if v is not None}}
    groups = {}
    for key, m in merged.items():
        # every row from its runs (a configuration's seeds may come from several files), its ± the sample sd over
        # seeds (ddof 1; None for one seed) where the files record the population one
        rows = {config_key(row): row for row in results_lib.summarize(m["runs"], m["task_metrics"], ddof=1)}
        m["summary"] = [{**row, **{k: v for k, v in rows[config_key(row)].items() if k != "hparams"}}
                        if config_key(row) in rows else row for row in m["summary"]]
        shows_protocol = key.protocol != BRAX or any(k[:2] == key[:2] and k.protocol != key.protocol for k in merged)
        title = group_title(key, m["protocol"], shows_protocol)
        if key.budget:
            title = title[:-1] + f", {key.budget:,} iterations)" if title.endswith(")") else \
                title + f" ({key.budget:,} iterations)"
        groups[key] = Group(**m, shows_protocol=shows_protocol, title=title)
    return groups


def _settings_but_seeds(res: results_lib.Results) -> dict:
    """What decides a file's runs beside their seeds: its settings as resolved (`Results.records`: a file recording
    the methods' knobs as recipe fields, or a former name, reads as today's), with `budget.seeds`,
    `budget.first_seed` and the protocol's description left out, and its data."""
    try:
        blocks = res.records().to_json()
    except (SettingsError, TypeError, ValueError):   # settings this code cannot resolve: compared as recorded
        blocks = json.loads(json.dumps(res.settings))
    blocks["budget"] = {k: v for k, v in (blocks.get("budget") or {}).items() if k not in ("seeds", "first_seed")}
    blocks["protocol"] = {k: v for k, v in (blocks.get("protocol") or {}).items() if k != "doc"}
    return {**blocks, "data": res.config.get("data", {}).get("settings")}


def _check_seed_split(res: results_lib.Results, row: dict, m: dict, where: str, group: str) -> None:
    """Refuses (`ReportError`) a configuration `res` shares with a file already in `m` unless the two are one
    sweep split by seeds (`--set budget.first_seed=K`): the same settings but the seeds, and no seed in both."""
    key = config_key(row)
    other = next(s for s in m["sources"] if key in {config_key(x) for x in s.summary})
    if _settings_but_seeds(res) != _settings_but_seeds(other):
        raise ReportError(f"{where}: {row['method']} {row['hparams']} is also in another results file of {group} "
                          f"({getattr(other, 'path', '') or 'unnamed'}) with other settings; pass one of them")
    seeds = {run["seed"] for run in res.runs if config_key(run) == key}
    both = seeds & {run["seed"] for run in m["runs"] if config_key(run) == key}
    if both:
        raise ReportError(f"{where}: {row['method']} {row['hparams']} is also in another results file of {group} "
                          f"with seed(s) {', '.join(map(str, sorted(both)))}; pass one of them")


def config_key(row: dict) -> tuple:
    """A summary row's or run's configuration, hashable: `(method, ((name, value), ...))`, names sorted."""
    return row["method"], tuple(sorted(row["hparams"].items()))


def is_rate(m: Group) -> bool:
    """Whether the merged results of `m` are judged by a rate in [0, 1] (reported in %), not by the return."""
    return m.metric != "return"


# -- groups: order, titles, file names -----------------------------------------------------------------------------

def _protocol_rank(p: dict) -> tuple:
    """Protocols in report order: the mujoco-state family by frame skip (the paper's first), then `brax`, then
    others."""
    if in_state_family(p["name"]):
        return 0, p.get("frame_skip") or 0, p["name"]
    return (1, 0, "") if p["name"] == BRAX else (2, 0, p["name"])


def ordered(merged: Merged) -> list[tuple[Key, Group]]:
    """`merged`'s items: the sweepable tasks first in their order (`ape_jax.tasks.sweepable`), then by name; within a
    task by observation mode, then protocol (`_protocol_rank`)."""
    order = {e: i for i, e in enumerate(tasks.sweepable())}
    return sorted(merged.items(), key=lambda kv: (order.get(kv[0][0], len(order)), kv[0][0], kv[0][1],
                                                  _protocol_rank(kv[1].protocol), kv[0].budget or 0))


def group_title(key: Key, protocol: dict, with_protocol: bool, with_obs: bool | None = None) -> str:
    """A group's title: `"Hopper"`, `"Hopper (image)"`, `"Hopper (mujoco-state, frame skip 2)"`, `"Hopper (image,
    brax)"`; the observation mode unless `with_obs` is False (default: unless a state task's `pos`)."""
    with_obs = not (key.obs == "pos" and key.env in MUJOCO) if with_obs is None else with_obs
    parts = [key.obs] if with_obs else []
    parts += [protocol_words(protocol)] if with_protocol else []
    if key.version is not None and key.version != current_task_version(key.env):  # the first tables' camera, ...
        parts.append(f"version {key.version}")
    if key.perception is not None:
        parts.append(encoder_words(key.perception))
    return tasks.get(key.env).title + (f" ({', '.join(parts)})" if parts else "")


def file_stem(m: Group) -> str:
    """A group's part of figure file names, unique per group: `hopper`, `hopper-image`, `hopper-mujoco-state-fs2`.

    `brax` groups keep the names they had before protocols existed; other protocols append their name.
    """
    parts = [m.env] + ([] if m.obs == "pos" else [m.obs])
    parts += [] if m.protocol["name"] == BRAX else [m.protocol["name"]]
    parts += [f"{m.budget}it"] if m.budget else []
    version = m.protocol.get("task_version")  # from the second on: the first's names stay as they were
    parts += [f"v{version}"] if version not in (None, 1) else []
    parts += [encoder_stem(m.protocol["perception"])] if m.protocol.get("perception") else []
    return "-".join(parts)


def groups_of(merged: Merged, obs: str, protocol: str) -> list[Group]:
    """The state tasks' (`MUJOCO`) groups with observations `obs` under `protocol`, in task order."""
    return [merged[k] for e in MUJOCO if (k := Key(e, obs, protocol)) in merged]


def protocols_of(merged: Merged, obs: str) -> list[str]:
    """The protocols of the state tasks' groups with observations `obs`, in report order (`_protocol_rank`)."""
    found = {m.protocol["name"]: m.protocol for k, m in ordered(merged) if k.env in MUJOCO and k.obs == obs}
    return sorted(found, key=lambda n: _protocol_rank(found[n]))
