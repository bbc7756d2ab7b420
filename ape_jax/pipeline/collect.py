"""Collecting expert demonstrations under jit, with optional noise in the executed actions (DART's, CARLA100's).

    demos = collect(env, expert, key, num_episodes=25)              # Demonstrations
    demos, meta, path, hit = collect_cached(settings, data_dir)     # the same, cached on disk

The expert acts on the full state (`env.expert_observation`); the dataset
records the observation in the environment's own mode. The executed action is
the expert's clipped to the action bounds (an unbounded Gaussian mean, e.g. FCA's
expert, is clipped as the FCA code clipped it: the reward's control cost reads the
action given); the label is that clipped action (`labels="clipped"`, the default)
or the expert's output as it gave it (`labels="raw"`, what FCA stored;
`ape_jax.tasks.Protocol.labels`). With noise (`noise_frac > 0`), each step's
executed action is, with probability `noise_frac`, the expert's action plus
Gaussian noise of std `noise_std` (clipped to the action bounds), while the
**clean** expert action is stored as the label (Laskey et al., 2017, as in the
paper's driving data). With `noise_steps > 1` the perturbation comes in bursts
(CARLA100's, Codevilla et al. 2019): a burst starts at an unperturbed step with
the chance that makes `noise_frac` of all steps perturbed
(`burst_start_probability`), lasts `noise_steps` steps, and adds to the clean
action an offset that rises and falls as a triangle to a Gaussian peak of std
`noise_std`; the expert sees the drift it caused and corrects it. The metadata
records the noise and the share of steps whose executed action differs from
the label (`noise.perturbed_share`). The metadata records the labels' mode and how many of the
expert's raw output's entries lay outside the action range (`label_statistics`).

A dataset names its expert (`setup.ExpertRef`'s description, in its data key); `dataset_expert`
finds it again for a sweep from the dataset (`--dataset`), with the references the
dataset recorded.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import time
from importlib.metadata import version
from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ape_jax import observations, tasks
from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.interrupts import CollectionInterrupted, compiled, compiling  # noqa: F401 (read here)
from ape_jax.pipeline import setup as setup_lib
from ape_jax.pipeline.setup import ExpertRef, variant_of
from ape_jax.pipeline.setup import protocol_setup, reference_returns  # noqa: F401  (the entry points import them here)

def default_episodes(env_name: str) -> int:
    """Expert episodes a sweep collects for `env_name` under the `brax` protocol (its task record's: ~20k training
    transitions for MuJoCo with a 20% validation split, ~1k samples for the driving sandbox)."""
    return tasks.get(env_name).episodes


def expert_for(env: envs.Env, variant: str | None = None) -> tuple[Callable[[jax.Array], jax.Array], dict]:
    """The expert of `env` as `full_obs -> action` (its output as it gives it: unbounded for a `"linear"` head; see
    `labeller`), and its description for metadata (`setup.ExpertRef`: a rule-based expert, the shipped checkpoint
    `envs/experts/<env>[-<variant>]/`, else an imported one of that name); `ExpertError` if there is none."""
    ref = ExpertRef.resolve(env.name, variant, env=env)
    return ref.policy(env), ref.description


def labeller(expert: Callable[[jax.Array], jax.Array], env: envs.Env,
             labels: str = "clipped") -> Callable[[jax.Array], jax.Array]:
    """The expert's label `full_obs [D] -> [A] float32` as `labels` says (`ape_jax.tasks.LABELS`): `"clipped"` to
    `env.action_bounds` (what it executes), or `"raw"`, as it gives it."""
    if labels not in tasks.LABELS:
        raise ValueError(f"labels {labels!r} is not one of {', '.join(tasks.LABELS)}")
    from envs import experts

    return experts.executed(expert, env.action_bounds) if labels == "clipped" else expert


def label_statistics(raw: np.ndarray, bounds: tuple) -> dict:
    """Of the expert's raw labels `raw [N, A]`: the share of entries outside the action range `bounds`
    (`env.action_bounds`), and the smallest and largest entry."""
    low, high = (np.asarray(b, np.float32) for b in bounds)
    raw = np.asarray(raw, np.float32)
    outside = (raw < low) | (raw > high)
    finite = lambda v: [float(x) if np.isfinite(x) else None for x in v]  # noqa: E731  JSON has no inf
    return {"raw_outside_share": float(outside.mean()) if raw.size else 0.0,
            "raw_outside_rows_share": float(outside.any(axis=-1).mean()) if raw.size else 0.0,
            "raw_min": float(raw.min()) if raw.size else None, "raw_max": float(raw.max()) if raw.size else None,
            "action_low": finite(low), "action_high": finite(high)}


def burst_start_probability(noise_frac: float, noise_steps: int) -> float:
    """The chance that a burst of `noise_steps` steps starts at an unperturbed step, so that in the long run a
    share `noise_frac` of the steps is perturbed: bursts of L steps apart by geometric gaps of mean (1 - p) / p
    steps perturb L / (L + (1 - p) / p) of them."""
    return noise_frac / (noise_frac + noise_steps * (1.0 - noise_frac)) if noise_frac > 0 else 0.0


def _noisy_expert(env: envs.Env, expert, noise_frac: float, noise_std: float, noise_steps: int = 1) -> envs.Policy:
    """The expert executing its clipped action, perturbed as the module docstring says: each step on its own
    (`noise_steps` 1), or in bursts whose offset rises and falls as a triangle over `noise_steps` steps."""
    low, high = env.action_bounds

    def clean_action(state):
        return jnp.clip(expert(env.expert_observation(state)), low, high)  # what the environment executes

    if noise_frac <= 0 or noise_std <= 0:
        return envs.stateless(lambda params, state, key: clean_action(state))
    if noise_steps == 1:
        def act(params, state, key):
            clean = clean_action(state)
            key_flip, key_noise = jax.random.split(key)
            noisy = jnp.clip(clean + noise_std * jax.random.normal(key_noise, clean.shape), low, high)
            return jnp.where(jax.random.uniform(key_flip) < noise_frac, noisy, clean)

        return envs.stateless(act)

    start_p = burst_start_probability(noise_frac, noise_steps)
    action_size = env.action_size

    def init(params, state):  # (steps of the burst left, its peak offset)
        return jnp.zeros((), jnp.int32), jnp.zeros((action_size,), jnp.float32)

    def act_burst(params, carry, state, key):
        left, peak = carry
        clean = clean_action(state)
        key_start, key_peak = jax.random.split(key)
        start = (left == 0) & (jax.random.uniform(key_start) < start_p)
        peak = jnp.where(start, noise_std * jax.random.normal(key_peak, clean.shape), peak)
        left = jnp.where(start, noise_steps, left)
        position = (noise_steps - left + 0.5) / noise_steps            # (0, 1) through the burst
        shape = jnp.where(left > 0, 1.0 - jnp.abs(2.0 * position - 1.0), 0.0)
        return jnp.clip(clean + shape * peak, low, high), (jnp.maximum(left - 1, 0), peak)

    return envs.Policy(init=init, act=act_burst)


def make_batch_collector(env: envs.Env, expert: Callable[[jax.Array], jax.Array], batch: int,
                         noise_frac: float = 0.0, noise_std: float = 0.0,
                         noise_steps: int = 1) -> Callable[[jax.Array], envs.Trajectory]:
    """A jitted `key -> Trajectory` of `batch` expert episodes; `extra` holds the expert's raw (clean) output as
    `label`, and the sim state; the executed action is clipped to the action bounds."""
    policy = _noisy_expert(env, expert, noise_frac, noise_std, noise_steps)

    def record(state):
        return {"label": expert(env.expert_observation(state)), "sim": _as_dict(env.sim_state(state))}

    return jax.jit(lambda k: envs.rollout(env, policy, None, k, batch, record=record))


CHUNK_STEPS = 100  # steps per jitted call of `collect`: a Ctrl-C waits for one chunk (ToyTown's 32 episodes: ~0.05 s)


def make_chunked_collector(env: envs.Env, expert: Callable[[jax.Array], jax.Array], batch: int,
                           noise_frac: float = 0.0, noise_std: float = 0.0, noise_steps: int = 1,
                           chunk: int = CHUNK_STEPS) -> Callable[[jax.Array], envs.Trajectory]:
    """`make_batch_collector`'s `key -> Trajectory`, run as chunks of `chunk` steps with the host between them.

    The steps are the batch collector's (the same keys; `envs.rollout.start` / `advance`), so the rows kept are
    too. A Ctrl-C (KeyboardInterrupt) is raised between two chunks, or at once while a program compiles
    (`compiled`), where one whole-episode call would hold it for its compile and the whole episode. The chunks
    stop once every episode has ended: the trajectory may have fewer than `env.episode_length` steps (the ones
    left out were all invalid).
    """
    from envs.rollout import advance, start

    policy = _noisy_expert(env, expert, noise_frac, noise_std, noise_steps)

    def record(state):
        return {"label": expert(env.expert_observation(state)), "sim": _as_dict(env.sim_state(state))}

    total = env.episode_length
    programs: dict = {}   # compiled once per collector: the start, and one per chunk length (a remainder: two)

    def program(name, fn, *args):
        if name not in programs:
            programs[name] = compiled(fn, *args)
        return programs[name]

    def run(key: jax.Array) -> envs.Trajectory:
        running = program("start", lambda k: start(env, policy, None, k, batch), key)(key)
        pieces = []
        for t in range(0, total, chunk):
            n = min(chunk, total - t)
            step = program(n, lambda r, n=n: advance(env, policy, None, r, n, record=record), running)
            running, piece = step(running)
            pieces.append(jax.device_get(piece))   # waits for the chunk; a Ctrl-C is raised after it
            if bool(running.all_done):
                break
        return jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *(p.replace(final=None) for p in pieces)
                            ).replace(final=jax.device_get(running.state))

    return run


def collect(env: envs.Env, expert: Callable[[jax.Array], jax.Array], key: jax.Array, num_episodes: int,
            noise_frac: float = 0.0, noise_std: float = 0.0, batch: int = 32,
            progress: Callable[[int], None] | None = None, labels: str = "clipped",
            noise_steps: int = 1) -> data_lib.Demonstrations:
    """Rolls out `expert` for `num_episodes` episodes and returns their transitions.

    Episodes run `batch` at a time (vmapped over episodes, `lax.scan` over
    `env.episode_length` steps) in jitted chunks of `CHUNK_STEPS` steps
    (`make_chunked_collector`: Ctrl-C stops it between chunks, nothing
    returned); the last batch is padded and trimmed, so the chunks compile once.

    Args:
      env: the environment, in the observation mode to record.
      expert: `full_obs [D] -> action [A]`, deterministic.
      key: PRNG key; batch i uses `fold_in(key, i)`.
      num_episodes: episodes to collect.
      noise_frac, noise_std, noise_steps: noise in the executed actions, each step on its own or in bursts
        (module docstring).
      batch: episodes per jitted call.
      progress: called with the number of episodes finished after each batch.
      labels: `"clipped"` (the label is the executed action, without noise) or `"raw"` (the expert's output).

    Returns:
      `Demonstrations` (NumPy arrays), episodes `0 .. num_episodes-1` in order; `executed` within the action
      bounds whatever `labels` says.

    Raises:
      CollectionInterrupted: Ctrl-C (a KeyboardInterrupt) while collecting; nothing is returned.
    """
    if labels not in tasks.LABELS:
        raise ValueError(f"labels {labels!r} is not one of {', '.join(tasks.LABELS)}")
    if num_episodes < 1 or batch < 1:
        raise ValueError(f"num_episodes and batch must be >= 1, got {num_episodes} and {batch}")
    if not 0.0 <= noise_frac <= 1.0 or noise_std < 0 or noise_steps < 1:
        raise ValueError(f"noise_frac must be in [0, 1], noise_std >= 0 and noise_steps >= 1, got {noise_frac}, "
                         f"{noise_std} and {noise_steps}")
    batch = min(batch, num_episodes)
    run = make_chunked_collector(env, expert, batch, noise_frac, noise_std, noise_steps)
    parts = []
    try:
        for i in range(-(-num_episodes // batch)):
            traj = run(jax.random.fold_in(key, i))
            keep = min(batch, num_episodes - i * batch)
            parts.append(_flatten(traj, keep, first_episode=i * batch))
            if progress:
                progress(min((i + 1) * batch, num_episodes))
    except KeyboardInterrupt:
        raise CollectionInterrupted(sum(len(np.unique(p.episode)) for p in parts), num_episodes) from None
    demos = jax.tree.map(lambda *xs: np.concatenate(xs), *parts)
    if labels == "clipped":
        demos = demos.replace(action=_clipped(demos.action, env))
    return demos


def _clipped(action: np.ndarray, env: envs.Env) -> np.ndarray:
    """`action` clipped to `env.action_bounds`: what the environment executes, and the `"clipped"` labels."""
    low, high = (np.asarray(b, np.float32) for b in env.action_bounds)
    return np.clip(action, low, high)


def _as_dict(sim: Any) -> dict:
    if isinstance(sim, dict):
        return sim
    return {f.name: getattr(sim, f.name) for f in dataclasses.fields(sim)}


def _flatten(traj: envs.Trajectory, keep: int, first_episode: int) -> data_lib.Demonstrations:
    valid = np.asarray(traj.valid[:keep]) > 0
    steps = valid.shape[1]
    rows = lambda x: np.asarray(x[:keep])[valid]  # noqa: E731  [keep, T, ...] -> [n, ...], episode-major
    episode = np.broadcast_to(np.arange(keep, dtype=np.int32)[:, None] + first_episode, valid.shape)
    t = np.broadcast_to(np.arange(steps, dtype=np.int32)[None, :], valid.shape)
    return data_lib.Demonstrations(
        obs=rows(traj.obs), action=rows(traj.extra["label"]).astype(np.float32),
        executed=rows(traj.action).astype(np.float32), episode=episode[valid], t=t[valid],
        done=rows(traj.done).astype(np.float32), reward=rows(traj.reward).astype(np.float32),
        sim={k: rows(v) for k, v in traj.extra["sim"].items()})


def data_key(env_name: str, obs: str, episodes: int, expert: str | None = None, *, seed: int = 0,
             noise_frac: float = 0.0, noise_std: float = 0.0, batch: int = 32, labels: str = "clipped",
             noise_steps: int = 1, **env_overrides) -> dict:
    """The collection settings that name a cached dataset (`setup.data_key`, whose arguments these are, in its
    order) for expert variant `expert` by name (None: the task's own): the environment's settings are checked by
    making it and the expert is resolved (a sweep's `Setup` does both once and calls `setup.data_key` itself)."""
    env = envs.make(env_name, obs=obs, **env_overrides)
    return setup_lib.data_key(env_name, obs, episodes, ExpertRef.resolve(env_name, expert, env=env), seed=seed,
                              noise_frac=noise_frac, noise_std=noise_std, batch=batch, labels=labels,
                              noise_steps=noise_steps, **env_overrides)


def collect_cached(cfg: dict, data_dir, force: bool = False, progress=None, save: bool = True,
                   references: dict | None = None, expert: ExpertRef | None = None):
    """The dataset of settings `cfg` (a data key: `setup.data_key`): loaded if cached, else collected by `expert`
    (its `ExpertRef`, whose policy is loaded once; None: the one `cfg` names, resolved again) and saved.

    `save=False` (a sweep's processes other than process 0) writes nothing, and
    collects rather than fail on a cached file it cannot read (another process
    may be writing it). `references` (`reference_returns`, or None) are recorded in the metadata of a dataset
    collected here (`"references"`), so a sweep from the file alone (`--dataset`) normalises by them.

    Returns:
      (demos, meta, path, cached): `cached` is True when nothing was collected.
    """
    if cfg.get("frames", "rollout") == "states":
        return _rendered(cfg, data_dir, force, progress, save, references, expert)
    path = data_lib.cache_path(data_dir, cfg)
    if path.exists() and not force:
        try:
            demos, meta = data_lib.load(path)
        except data_lib.DataError:
            if save:
                raise
            meta = {}
        if meta.get("settings") == json.loads(json.dumps(cfg)):
            return demos, meta, path, True
    env = envs.make(cfg["env"], obs=cfg["obs"], **{k: (tuple(v) if isinstance(v, list) else v)
                                                     for k, v in cfg["env_overrides"].items()})
    policy = (expert or ExpertRef.of_key(cfg)).policy(env)
    labels = cfg.get("labels", "clipped")
    t0 = time.perf_counter()
    demos = collect(env, policy, jax.random.PRNGKey(cfg["seed"]), cfg["episodes"], cfg["noise_frac"],
                    cfg["noise_std"], cfg["batch"], progress, labels="raw", noise_steps=cfg.get("noise_steps", 1))
    seconds = time.perf_counter() - t0
    label_stats = {"mode": labels, **label_statistics(demos.action, env.action_bounds)}
    if labels == "clipped":
        demos = demos.replace(action=_clipped(demos.action, env))
    returns = np.bincount(demos.episode, weights=demos.reward)
    lengths = np.bincount(demos.episode)
    meta = {
        "env": cfg["env"], "obs": cfg["obs"], "seed": cfg["seed"],
        "noise": {"frac": cfg["noise_frac"], "std": cfg["noise_std"], "steps": cfg.get("noise_steps", 1),
                  "perturbed_share": float(np.any(demos.executed != _clipped(demos.action, env), axis=-1).mean())},
        "expert": cfg["expert"], "settings": cfg, "labels": label_stats,
        **({"references": dict(references)} if references is not None else {}),
        "episode_return_mean": float(returns.mean()), "episode_return_std": float(returns.std()),
        "episode_length_mean": float(lengths.mean()),
        "collect_s": round(seconds, 2), "backend": jax.default_backend(),
        "versions": {p: version(p) for p in ("jax", "brax", "mujoco", "mujoco-mjx", "numpy")},
    }
    if save:
        meta = data_lib.save(path, demos, meta)
    return demos, meta, path, False


RENDER_CHUNK = 1024  # frames per jitted call of `render_states` (one compile, bounded memory)


def render_states(env: envs.Env, sim: dict, chunk: int = RENDER_CHUNK) -> tuple[np.ndarray, float, float]:
    """`(frames [N, H, W, 3] uint8, compile_s, render_s)`: the frame `env` (an image environment) renders of each
    row's simulator state `sim` (`{"qpos": [N, nq], "qvel": [N, nv]}`, `Demonstrations.sim`), at most `chunk` rows
    per jitted, vmapped call (`observations.observe_rows`)."""
    return observations.observe_rows(env, sim, min(chunk, len(next(iter(sim.values())))))


def _rendered(cfg: dict, data_dir, force: bool, progress, save: bool, references: dict | None,
              expert: ExpertRef | None):
    """`collect_cached` of a `frames: "states"` image dataset: its state dataset (`setup.state_source`: loaded, or
    collected and saved) with each row's frame rendered from its simulator state (`render_states`). The frames
    are not saved: they are made again, in seconds on a GPU, from the states; `path` is the state dataset's."""
    source = setup_lib.state_source(cfg)
    demos, meta, path, cached = collect_cached(source, data_dir, force, progress, save, references, expert)
    env = envs.make(cfg["env"], obs="image", **{k: (tuple(v) if isinstance(v, list) else v)
                                                 for k, v in cfg["env_overrides"].items()})
    frames, compile_s, seconds = render_states(env, demos.sim)
    meta = {**meta, "obs": "image", "settings": cfg,
            "frames": {"from": "states", "state_dataset": path.name, "shape": list(frames.shape[1:]),
                       "compile_s": round(compile_s, 2), "render_s": round(seconds, 2),
                       "frames_per_s": round(len(frames) / max(seconds, 1e-9)), "backend": jax.default_backend()}}
    return demos.replace(obs=frames), meta, path, cached


@dataclasses.dataclass(frozen=True)
class DatasetExpert:
    """The expert a dataset from a file (`--dataset`) names, found again, and the returns to normalise by.

    Attributes:
      expert: the expert as `full_obs -> action` (its raw output, `expert_for`'s), None where none can be loaded.
      description: how the dataset describes its expert (`expert_for`'s description), None where it names none.
      references: `return_mean`, `return_std` (or None), `random_return_mean`: the dataset's recorded ones, else its
        expert's under the protocol; None where neither gives any (or the task has no return to normalise).
      why: why `expert` is None (a phrase), else None.
      references_from: `"dataset"`, `"expert"` or None.
    """

    expert: Callable[[jax.Array], jax.Array] | None
    description: dict | None
    references: dict | None
    why: str | None = None
    references_from: str | None = None


def dataset_expert(env: envs.Env, task: tasks.Task, protocol: tasks.Protocol, meta: dict | None,
                   where: str) -> DatasetExpert:
    """The expert of a dataset whose metadata is `meta` (`minari_io.dataset_metadata`: the collection `settings`,
    recorded `references`), for a sweep of `protocol` on `env`, whose task record is `task`.

    The dataset's expert is the one its settings describe, if the expert of that name here is still that one
    (the description `expert_for` gives now equals the recorded one: the same card, or the same imported file);
    a dataset that names none (your own, a Minari dataset from elsewhere) has the protocol's variant, if
    `protocol.expert` names one, else none. References: the dataset's own recorded ones first (ours, or Minari's
    `ref_min_score` / `ref_max_score`), else its expert's under the protocol (`envs.experts.reference`).

    Raises:
      ValueError: a dataset that names another expert than `protocol.expert` (one line, naming the `--set` that
        fits it).
    """
    from envs import experts

    meta = meta or {}
    description = (meta.get("settings") or {}).get("expert") if isinstance(meta.get("settings"), dict) else None
    variant = protocol.expert
    if description is not None:
        variant = variant_of(env.name, description)
        if variant != protocol.expert:
            name = "the task's own expert" if variant is None else f"expert {variant!r}"
            fix = "drop --set protocol.expert" if variant is None else f"pass --set protocol.expert={variant}"
            raise ValueError(f"{where} was collected by {name}, not the protocol's "
                             f"{'task expert' if protocol.expert is None else repr(protocol.expert)}; {fix}")
    expert, why = None, None
    if description is None and variant is None:
        why = f"{where} names no expert (set protocol.expert to a shipped or imported one that made it)"
    else:
        try:
            ref = ExpertRef.resolve(env.name, variant, env=env)
            expert, now = ref.policy(env), ref.description
            if description is not None and json.loads(json.dumps(now)) != description:
                expert = None
                why = (f"{where}'s expert {now.get('name') or now.get('path') or now.get('kind')} is not the one "
                       "that collected it any more (its card or file changed)")
        except (experts.ExpertError, ValueError) as e:
            why = f"{where}'s expert cannot be loaded: {e}"
    references, source = None, None
    recorded = meta.get("references")
    if task.has_card and isinstance(recorded, dict) and recorded.get("return_mean") is not None:
        references, source = {"return_mean": float(recorded["return_mean"]),
                              "return_std": None if recorded.get("return_std") is None
                              else float(recorded["return_std"]),
                              "random_return_mean": float(recorded["random_return_mean"])}, "dataset"
    elif task.has_card and expert is not None:
        try:
            name = env.name if variant is None else f"{env.name}-{variant}"
            references, source = experts.reference(name, protocol.reference or protocol.name), "expert"
        except experts.ExpertError:
            pass
    return DatasetExpert(expert, description, references, why, source)


def check_labels(demos: data_lib.Demonstrations, env: envs.Env, labels: str, where: str) -> None:
    """Refuses (ValueError, one line) demonstrations whose labels leave `env`'s action range unless `labels` is
    `"raw"` (`protocol.labels`: the protocol's consent to train on them as they are)."""
    if labels == "raw":
        return
    stats = label_statistics(demos.action, env.action_bounds)
    if stats["raw_outside_share"] > 0:
        low, high = (np.asarray(b, np.float32) for b in env.action_bounds)
        span = (f"[{low.min():g}, {high.max():g}]" if low.min() == low.max() and high.min() == high.max()
                else "its bounds")
        raise ValueError(f"{where}: {stats['raw_outside_share']:.1%} of its label entries lie outside {env.name}'s "
                         f"action range {span} (from {stats['raw_min']:.3g} to {stats['raw_max']:.3g}: raw labels, "
                         "e.g. a Gaussian expert's mean); pass --set protocol.labels=raw to train on them as they are")


def no_references_advice(found: DatasetExpert, where: str) -> str:
    """One line: why a dataset gives no returns to normalise by, and how to add them."""
    if str(where).endswith((".npz", ".json")):
        how = (f"add \"references\": {{\"return_mean\": R_EXPERT, \"random_return_mean\": R_RANDOM}} to "
               f"{pathlib.Path(where).with_suffix('.json').name}")
    else:
        how = "add ref_max_score (the expert's mean return) and ref_min_score (a random policy's) to its metadata.json"
    why = found.why or "its expert has no references under this protocol"
    return (f"{where} records no reference returns and {why}; the table reports returns only. To normalise, {how}"
            + (", or name the expert that made it with --set protocol.expert=NAME" if found.description is None
               else ""))
