"""A sweep through a perception encoder: the environment that observes embeddings, the demonstrations embedded once.

    encoder = resolve(env_name, recipe.perception, sha256)       # the file the recipe names, checked
    env, demos = perceive(camera_env, demos, encoder)            # `Perceived(env)`, `demos.obs` embedded

`recipe.perception` is `"none"` (the default: policies learn from pixels), `"task"` (the task's shipped encoder,
`envs/perception/<task>.npz`, made by `python -m experiments.perception --env <task>`) or a path to an encoder file
(`card`'s format: a user's own). The encoder is frozen: each frame's embedding is computed once for the
demonstrations and once per step in a rollout, so a method's update costs what a state update costs, and the
history is the stack of per-frame embeddings. Every policy then is a state policy on `[E]` vectors (the recipe's
state network), standardised with the training rows' statistics as a state is.
"""

from __future__ import annotations

import pathlib
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs.base import Env, State, Wrapper
from ape_jax.perception import card as card_lib
from ape_jax.perception.card import Encoder, PerceptionError
from ape_jax.perception.net import embedder, in_chunks, reader

SHIPPED = pathlib.Path(__file__).resolve().parents[2] / "envs" / "perception"
NONE, TASK = "none", "task"
_LOADED: dict[tuple[str, str | None], Encoder] = {}


def shipped_path(env_name: str) -> pathlib.Path:
    return SHIPPED / f"{env_name}.npz"


def resolve(env_name: str, perception: str, sha256: str | None = None) -> Encoder:
    """The encoder `recipe.perception` names for task `env_name` (`"task"`: its shipped one; else a file's path),
    loaded once per process. `PerceptionError` (one line): a task without a perception card asked for `"task"`, a
    missing, truncated or malformed file, a SHA-256 other than `sha256` (when given)."""
    if perception == TASK:
        from ape_jax import tasks

        if tasks.get(env_name).perception is None:
            with_card = [t for t in tasks.sweepable() if tasks.get(t).perception is not None]
            raise PerceptionError(f"recipe.perception=task: {env_name} declares no perception card (tasks with one: "
                                  f"{', '.join(with_card)}); give an encoder file's path instead")
        path = shipped_path(env_name)
        if not path.is_file():
            raise PerceptionError(f"{path}: {env_name}'s encoder is not there; make it with python -m "
                                  f"experiments.perception --env {env_name}")
    else:
        path = pathlib.Path(perception).expanduser()
    key = (str(path.resolve()) if path.exists() else str(path), sha256)
    if key not in _LOADED:
        _LOADED[key] = card_lib.load(path, sha256)
    return _LOADED[key]


def loaded(sha256: str) -> Encoder:
    """The encoder of SHA-256 `sha256` that this process has resolved (`resolve`): where a policy that fine-tunes it
    finds its network and starting weights (`ape_jax.perception.tuned`). `PerceptionError` where none has been."""
    for encoder in _LOADED.values():
        if encoder.sha256 == sha256:
            return encoder
    raise PerceptionError(f"no perception encoder with SHA-256 {sha256[:12] or '(none)'}… is loaded in this process: "
                          f"resolve the recipe's (recipe.perception) before building its policy")


def check_sweep(encoder: Encoder, env: Env) -> None:
    """`card.check_fits` against the frames of `env` (the sweep's camera environment, collection settings)."""
    cfg = getattr(env, "config", None)
    card_lib.check_fits(encoder, env.name, tuple(getattr(cfg, "image_size", env.observation_shape[:2])),
                        getattr(cfg, "task_version", None), getattr(cfg, "weather", None))


OUTPUTS = ("embedding", "readout")   # what a policy sees of a frame (`recipe.perception_output`)


def seeing(encoder: Encoder, output: str = "embedding"):
    """`frames [..., H, W, 3] uint8 -> [..., F] float32`: what a policy sees of each frame: the encoder's embedding
    (`[E]`), or its read-out of the targets in their own units (`[D]`, the one-frame state as the encoder reads it)."""
    if output == "readout":
        scales = encoder.card.get("near") or {}
        return reader(encoder.net, encoder.params, encoder.card["target_mean"], encoder.card["target_std"],
                      [scales.get(t) for t in encoder.card["targets"]])
    if output != "embedding":
        raise PerceptionError(f"recipe.perception_output: one of {', '.join(OUTPUTS)}, got {output!r}")
    return embedder(encoder.net, encoder.params)


def embed_frames(encoder: Encoder, frames: np.ndarray, progress=None, output: str = "embedding") -> np.ndarray:
    """`[N, F] float32`: what a policy sees of each of `frames` `[N, H, W, 3] uint8` (`seeing`), in jitted chunks."""
    return in_chunks(seeing(encoder, output), np.asarray(frames), progress=progress)


def perceive(env: Env, demos: Any, encoder: Encoder, progress=None, output: str = "embedding") -> tuple[Env, Any]:
    """`(Perceived(env, encoder, output), demos with each frame replaced by what the policy sees of it)`."""
    if len(env.observation_shape) != 3:
        raise PerceptionError(f"recipe.perception reads camera frames; {env.name!r} observes "
                              f"{list(env.observation_shape)} (--obs image)")
    return Perceived(env, encoder, output), demos.replace(obs=embed_frames(encoder, demos.obs, progress, output))


class Perceived(Wrapper):
    """`env` (a camera environment) whose observation is what a frozen encoder makes of its frame (`seeing`: the
    embedding, `[E] float32`, or the read-out, `[D]`). Everything else (the simulator, rewards, `done`, metrics, the
    expert's observation, rendering) is `env`'s (`envs.base.Wrapper`)."""

    def __init__(self, env: Env, encoder: Encoder, output: str = "embedding"):
        super().__init__(env)
        self.encoder, self.output = encoder, output
        self._embed = seeing(encoder, output)
        self._size = encoder.embedding_size if output == "embedding" else len(encoder.card["targets"])

    def _seen(self, state: State) -> State:
        return state.replace(obs=self._embed(state.obs).astype(np.float32))

    def reset(self, key: jax.Array) -> State:
        return self._seen(self.inner.reset(key))

    def step(self, state: State, action: jax.Array) -> State:
        # the inner environment steps from an observation of its own shape; its value matters only where the step is
        # refused (`Env.step` keeps the state as given, `done`), so a blank frame spares a second render per step
        blank = jnp.zeros(self.inner.observation_shape, self.inner.observation_dtype)
        return self._seen(self.inner.step(state.replace(obs=blank), action))

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (self._size,)

    @property
    def observation_dtype(self):
        return np.float32

    def observe_sim(self, sim):
        return self._embed(self.inner.observe_sim(sim))

    def __repr__(self) -> str:
        return f"<Perceived {self.inner!r} through {pathlib.Path(self.encoder.path).name} ({self.output})>"
