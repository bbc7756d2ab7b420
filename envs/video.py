"""Write rollouts as pictures a person can look at: an animated GIF and PNG frames."""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
from PIL import Image

from envs.base import Env
from envs.rollout import Policy, rollout


def render_rollout(env: Env, policy: Policy, params: Any, key: jax.Array, num_steps: int) -> np.ndarray:
    """Rolls out one episode and renders every pre-step state inside jit.

    Returns:
      `[T, H, W, 3] uint8` frames (the frozen last state repeats after `done`).
    """
    run = jax.jit(lambda k: rollout(env, policy, params, k, 1, num_steps, record=env.render))
    return np.asarray(run(key).extra[0])


def render_sim_states(env: Env, sim: Any, chunk: int = 256) -> np.ndarray:
    """Renders recorded simulator states (`env.sim_state`, leading dim `[T]`) as `[T, H, W, 3] uint8`.

    `env` must have `obs="image"`; this is how a dataset collected with state
    observations is looked at, or re-observed as images, after the fact.
    """
    if env.obs_mode != "image":
        raise ValueError(f"render_sim_states needs an image env, got obs={env.obs_mode!r}")
    render = jax.jit(jax.vmap(env.observe_sim))
    n = len(jax.tree.leaves(sim)[0])
    return np.concatenate([np.asarray(render(jax.tree.map(lambda x: x[i:i + chunk], sim)))
                           for i in range(0, n, chunk)])


def save_frames(frames: np.ndarray, path: str, fps: int = 20, scale: int = 1) -> list[str]:
    """Writes `[T, H, W, 3] uint8` frames as a GIF (`path` ends in .gif) or PNGs (a folder).

    Args:
      frames: the frames.
      path: `something.gif` for one animated GIF, otherwise a directory that
        receives `frame_0000.png`, ...
      fps: GIF frame rate.
      scale: integer upscaling (nearest neighbour), handy for 64×64 frames.

    Returns:
      The paths written.
    """
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames must be [T, H, W, 3] uint8, got {frames.shape} {frames.dtype}")
    images = [Image.fromarray(f) for f in frames]
    if scale > 1:
        images = [im.resize((im.width * scale, im.height * scale), Image.NEAREST) for im in images]
    if path.endswith(".gif"):
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        images[0].save(path, save_all=True, append_images=images[1:], duration=max(1, round(1000 / fps)), loop=0)
        return [path]
    os.makedirs(path, exist_ok=True)
    paths = []
    for i, im in enumerate(images):
        paths.append(os.path.join(path, f"frame_{i:04d}.png"))
        im.save(paths[-1])
    return paths
