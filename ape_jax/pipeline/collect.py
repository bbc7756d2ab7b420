"""Collecting expert demonstrations under jit, with optional DART-style noise.

    demos = collect(env, expert, key, num_episodes=25)              # Demonstrations
    demos, meta, path, hit = collect_cached(settings, data_dir)     # the same, cached on disk

The expert acts on the full state (`env.expert_observation`); the dataset
records the observation in the environment's own mode. With noise
(`noise_frac > 0`), each step's executed action is, with probability
`noise_frac`, the expert's action plus Gaussian noise of std `noise_std`
(clipped to the action bounds), while the **clean** expert action is stored as
the label (Laskey et al., 2017, as in the paper's driving data).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from importlib.metadata import version
from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

import envs
from ape_jax import tasks
from ape_jax.pipeline import data as data_lib

def default_episodes(env_name: str) -> int:
    """Expert episodes a sweep collects for `env_name` under the `brax` protocol (its task record's: ~20k training
    transitions for MuJoCo with a 20% validation split, ~1k samples for the driving sandbox)."""
    return tasks.get(env_name).episodes


@dataclasses.dataclass(frozen=True)
class ProtocolSetup:
    """A protocol as it applies to one environment: what the sweep, `experiments.collect` and the keyframe picture
    collect under it, so the three name the same cached dataset.

    Attributes:
      name: the protocol's name (`ape_jax.tasks.PROTOCOLS`).
      settings: every field, resolved for the environment (results.json's `protocol`).
      env_overrides: the `envs.make` settings it fixes (frame skip, episode length, reward scale).
      episodes: expert episodes to collect: as many whole episodes as its expert steps take, else the task's.
      expert: the expert variant demonstrating (`ape_jax.tasks.Protocol.expert`; None: the task's own).
    """

    name: str
    settings: dict
    env_overrides: dict
    episodes: int
    expert: str | None = None


def protocol_setup(env_name: str, obs: str, protocol: str | tasks.Protocol | None = None) -> ProtocolSetup:
    """Protocol `protocol` (a name, None: the task's default for `obs`, or a record, e.g. with `--set` changes) for
    `env_name`; `ValueError` for one the task cannot take."""
    if isinstance(protocol, tasks.Protocol):
        tasks.get(env_name).protocol(protocol.name, obs)  # ValueError for a protocol the task cannot take
        proto = protocol
    else:
        proto = tasks.get(env_name).protocol(protocol, obs)
    brax = env_name in envs.brax_env.brax_names()
    standard = envs.brax_env.default_frame_skip(env_name) if brax else None
    settings = proto.settings(standard)
    if settings["episode_length"] is None:
        settings["episode_length"] = envs.make(env_name, obs="full" if brax else None).episode_length
    episodes = (-(-proto.collect_transitions // settings["episode_length"]) if proto.collect_transitions is not None
                else proto.episodes or default_episodes(env_name))
    return ProtocolSetup(proto.name, settings, proto.env_overrides(standard), episodes, proto.expert)


def reference_returns(env_name: str, protocol: tasks.Protocol) -> dict | None:
    """The returns results are normalised by under `protocol` (`envs.experts.reference`: the expert's mean return
    `return_mean` and a random policy's `random_return_mean`, measured under the protocol), None for a task
    whose expert has no card (a rule-based one, e.g. ToyCar's).

    Raises:
      envs.experts.ExpertError: no reference measured under the protocol (naming the command that measures it).
    """
    if not tasks.get(env_name).has_card:
        return None
    from envs import experts

    return experts.reference(protocol.expert_name(env_name), protocol.reference or protocol.name)


def expert_for(env: envs.Env, variant: str | None = None) -> tuple[Callable[[jax.Array], jax.Array], dict]:
    """The expert of `env` as `full_obs -> action`, and a description of it for metadata.

    A task with a rule-based expert (`ape_jax.tasks.Task.expert`) uses the
    environment's own `expert`; any other uses the shipped checkpoint
    (`envs.experts.load`: `envs/experts/<env>/`, or with `variant` the one shipped beside it,
    `envs/experts/<env>-<variant>/`), which raises `ExpertError` if missing.
    """
    from envs import experts

    if tasks.get(env.name).expert == "rule-based":
        if variant is not None:
            raise ValueError(f"{env.name}'s expert is rule-based: it has no variant {variant!r} (protocol.expert)")
        # the rule and the physics it drives are code: their settings name the data (a changed default,
        # e.g. ToyCar's rolling resistance, must not reuse demonstrations cached before it)
        config = getattr(env, "config", None)
        config = json.loads(json.dumps(dataclasses.asdict(config))) if dataclasses.is_dataclass(config) else None
        return env.expert, {"kind": "rule-based", "function": f"{type(env).__module__}.expert_action",
                            "config": config}
    name = env.name if variant is None else f"{env.name}-{variant}"
    policy = experts.load(name)
    card_file = experts.directory(name) / experts.CARD
    card = experts.card(name)
    return policy, {
        "kind": "checkpoint", "path": f"envs/experts/{name}",
        "card_sha256": hashlib.sha256(card_file.read_bytes()).hexdigest(),
        "algorithm": card.get("algorithm"), "return_mean": card.get("return_mean"),
        "return_std": card.get("return_std"), "random_return_mean": card.get("random_return_mean"),
        "env_steps": card.get("env_steps"),
    }


def _noisy_expert(env: envs.Env, expert, noise_frac: float, noise_std: float) -> envs.Policy:
    low, high = env.action_bounds

    def act(params, state, key):
        clean = expert(env.expert_observation(state))
        if noise_frac <= 0 or noise_std <= 0:
            return clean
        key_flip, key_noise = jax.random.split(key)
        noisy = jnp.clip(clean + noise_std * jax.random.normal(key_noise, clean.shape), low, high)
        return jnp.where(jax.random.uniform(key_flip) < noise_frac, noisy, clean)

    return envs.stateless(act)


def make_batch_collector(env: envs.Env, expert: Callable[[jax.Array], jax.Array], batch: int,
                         noise_frac: float = 0.0, noise_std: float = 0.0) -> Callable[[jax.Array], envs.Trajectory]:
    """A jitted `key -> Trajectory` of `batch` expert episodes; `extra` holds the clean label and sim state."""
    policy = _noisy_expert(env, expert, noise_frac, noise_std)

    def record(state):
        return {"label": expert(env.expert_observation(state)), "sim": _as_dict(env.sim_state(state))}

    return jax.jit(lambda k: envs.rollout(env, policy, None, k, batch, record=record))


def collect(env: envs.Env, expert: Callable[[jax.Array], jax.Array], key: jax.Array, num_episodes: int,
            noise_frac: float = 0.0, noise_std: float = 0.0, batch: int = 32,
            progress: Callable[[int], None] | None = None) -> data_lib.Demonstrations:
    """Rolls out `expert` for `num_episodes` episodes and returns their transitions.

    Episodes run `batch` at a time in one jitted program (vmapped over
    episodes, `lax.scan` over `env.episode_length` steps); the last batch is
    padded and trimmed, so there is one compilation.

    Args:
      env: the environment, in the observation mode to record.
      expert: `full_obs [D] -> action [A]`, deterministic.
      key: PRNG key; batch i uses `fold_in(key, i)`.
      num_episodes: episodes to collect.
      noise_frac, noise_std: DART-style noise (module docstring).
      batch: episodes per jitted call.
      progress: called with the number of episodes finished after each batch.

    Returns:
      `Demonstrations` (NumPy arrays), episodes `0 .. num_episodes-1` in order.
    """
    if num_episodes < 1 or batch < 1:
        raise ValueError(f"num_episodes and batch must be >= 1, got {num_episodes} and {batch}")
    if not 0.0 <= noise_frac <= 1.0 or noise_std < 0:
        raise ValueError(f"noise_frac must be in [0, 1] and noise_std >= 0, got {noise_frac} and {noise_std}")
    batch = min(batch, num_episodes)
    run = make_batch_collector(env, expert, batch, noise_frac, noise_std)
    parts = []
    for i in range(-(-num_episodes // batch)):
        traj = jax.device_get(run(jax.random.fold_in(key, i)))
        keep = min(batch, num_episodes - i * batch)
        parts.append(_flatten(traj, keep, first_episode=i * batch))
        if progress:
            progress(min((i + 1) * batch, num_episodes))
    return jax.tree.map(lambda *xs: np.concatenate(xs), *parts)


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


def settings(env_name: str, obs: str, episodes: int, seed: int = 0, noise_frac: float = 0.0,
             noise_std: float = 0.0, batch: int = 32, expert: str | None = None, **env_overrides) -> dict:
    """The collection settings that name a cached dataset (see `data.cache_path`); `expert`: the expert variant
    (`expert_for`; None: the task's own), named through its card in the settings' `expert`."""
    env = envs.make(env_name, obs=obs, **env_overrides)
    _, expert_info = expert_for(env, expert)
    overrides = {k: (list(v) if isinstance(v, tuple) else v) for k, v in sorted(env_overrides.items())}
    return {"env": env_name, "obs": obs, "episodes": int(episodes), "seed": int(seed),
            "noise_frac": float(noise_frac), "noise_std": float(noise_std), "batch": int(batch),
            "env_overrides": overrides, "expert": expert_info, "format": data_lib.FORMAT}


def _variant(cfg: dict) -> str | None:
    """The expert variant collection settings name (`settings`): the suffix of the expert's directory, if any."""
    path = (cfg.get("expert") or {}).get("path") or ""
    name = path.rsplit("/", 1)[-1]
    return name[len(cfg["env"]) + 1:] if name.startswith(cfg["env"] + "-") else None


def collect_cached(cfg: dict, data_dir, force: bool = False, progress=None, save: bool = True):
    """The dataset of settings `cfg` (from `settings`): loaded if cached, else collected and saved.

    `save=False` (a sweep's processes other than process 0) writes nothing, and
    collects rather than fail on a cached file it cannot read (another process
    may be writing it).

    Returns:
      (demos, meta, path, cached): `cached` is True when nothing was collected.
    """
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
    expert, _ = expert_for(env, _variant(cfg))
    t0 = time.perf_counter()
    demos = collect(env, expert, jax.random.PRNGKey(cfg["seed"]), cfg["episodes"], cfg["noise_frac"],
                    cfg["noise_std"], cfg["batch"], progress)
    seconds = time.perf_counter() - t0
    returns = np.bincount(demos.episode, weights=demos.reward)
    lengths = np.bincount(demos.episode)
    meta = {
        "env": cfg["env"], "obs": cfg["obs"], "seed": cfg["seed"],
        "noise": {"frac": cfg["noise_frac"], "std": cfg["noise_std"]},
        "expert": cfg["expert"], "settings": cfg,
        "episode_return_mean": float(returns.mean()), "episode_return_std": float(returns.std()),
        "episode_length_mean": float(lengths.mean()),
        "collect_s": round(seconds, 2), "backend": jax.default_backend(),
        "versions": {p: version(p) for p in ("jax", "brax", "mujoco", "mujoco-mjx", "numpy")},
    }
    if save:
        meta = data_lib.save(path, demos, meta)
    return demos, meta, path, False
