"""Watching a trained policy act: one evaluation episode of a finished sweep's saved policy, as a captioned GIF.

    clip = episode_of(results.load("OUT/results.json"), "OUT/params", "bc-oh", seed=0)
    write_gif(clip, "bc-oh.gif")

The policy is rolled out exactly as the sweep evaluated it (`sweep.evaluate_group`: the same environment, the
same observation statistics and history, the same `EVAL_SEED` and number of episodes, so episode `e` here is
episode `e` of its recorded evaluation), recording the simulator's state at every step; the states are then
rendered inside `jit` by the task's renderer (`envs.video.render_sim_states`, what `experiments.collect
--preview` shows of the expert), at `size` for state observations. Each frame carries a caption: the method,
its settings and seed, the step, and the return so far out of the episode's.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from collections.abc import Callable

import jax
import numpy as np

from ape_jax.pipeline import checkpoint as ckpt_lib
from ape_jax.pipeline import sweep as sweep_lib
from ape_jax.pipeline.data import write_atomic
from ape_jax.pipeline.results import Results


class WatchError(ValueError):
    """The policy asked for cannot be shown (one line, for the command line)."""


@dataclasses.dataclass(frozen=True)
class Clip:
    """One episode of one policy, rendered.

    Attributes:
      frames: `[T', H, W, 3] uint8`, every `stride`-th step of the episode up to its end.
      steps: the step of each frame, `[T']`.
      rewards: the reward of every step of the episode, `[T]` (0 after it ended).
      title: what the caption names: the method's label, its settings and seed.
      episode_return: the episode's return; `mean_return`: the mean over the evaluation's episodes, as recorded.
      metric: the task's main metric (results.json's `main_metric`: `return`, or e.g. ToyCar's `success`);
        `episode_metric`, `mean_metric`: its value in this episode and its mean over the evaluation's episodes.
      fps: the frame rate that plays the episode in real time (at most 50 frames per second).
    """

    frames: np.ndarray
    steps: np.ndarray
    rewards: np.ndarray
    title: str
    episode_return: float
    mean_return: float
    metric: str
    episode_metric: float
    mean_metric: float
    fps: int


def parse_choice(text: str) -> tuple[str, int | None]:
    """`"METHOD[:SEED]"` -> (method, seed or None); raises `WatchError` for a seed that is not an integer."""
    method, _, seed = text.partition(":")
    if not method:
        raise WatchError(f"--video {text!r}: name a method, as METHOD or METHOD:SEED")
    if seed and not seed.lstrip("-").isdigit():
        raise WatchError(f"--video {text!r}: the seed after ':' must be an integer")
    return method, int(seed) if seed else None


def choose_run(results: Results, method: str, seed: int | None) -> dict:
    """The run record to show: `method`'s (its configuration with the best mean over seeds of the task's main
    metric, `results.main_metric`, where it ran several, as the report's "best" rows choose), at `seed`
    (default: its first)."""
    runs = [r for r in results.runs if r["method"] == method and r.get("status", "ok") == "ok"]
    if not runs:
        ran = sorted({r["method"] for r in results.runs})
        raise WatchError(f"no trained policy of method {method!r} in this sweep; it ran: {', '.join(ran)}")
    settings = {}
    for r in runs:
        settings.setdefault(json_key(r["hparams"]), []).append(r)
    key = "return_mean" if results.main_metric == "return" else results.main_metric
    best = max(settings.values(), key=lambda rs: np.mean([r["eval"][key] for r in rs]))
    if seed is None:
        return min(best, key=lambda r: r["seed"])
    chosen = [r for r in best if r["seed"] == seed]
    if not chosen:
        raise WatchError(f"method {method!r} has no seed {seed}; its seeds: {', '.join(str(r['seed']) for r in best)}")
    return chosen[0]


def json_key(hparams: dict) -> tuple:
    return tuple(sorted(hparams.items()))


def episode_of(results: Results, params_dir: str | pathlib.Path, method: str, seed: int | None = None,
               episode: int = 0, data_dir=None, size: tuple[int, int] = (128, 128), max_frames: int = 300,
               log: Callable[[str], None] = print) -> Clip:
    """Episode `episode` of the evaluation of `method`'s policy (`choose_run`), rendered (module docstring).

    Args:
      results, params_dir: a finished sweep's results (`results.load`) and its `params/`.
      data_dir: the demonstration cache (default: `ape_jax.pipeline.data.cache_dir()`); the observation
        statistics come from the demonstrations, collected again if missing.
      size: the frames' size for a sweep on state observations (an image sweep's frames are its own).
      max_frames: the episode is shown every `ceil(T / max_frames)`-th step.

    Raises:
      WatchError: no such method, seed or episode, or policies that are missing or not the sweep's.
    """
    import envs
    from envs import video
    from ape_jax.pipeline.reevaluate import spec_of

    record = choose_run(results, method, seed)
    spec = spec_of(results, data_dir)
    if not 0 <= episode < spec.budget.eval_episodes:
        raise WatchError(f"episode {episode} is not one of the evaluation's {spec.budget.eval_episodes} "
                         f"(0 to {spec.budget.eval_episodes - 1})")
    try:
        policies = ckpt_lib.load_policies(params_dir)
    except ckpt_lib.PolicyError as e:
        raise WatchError(str(e)) from None
    found = [(name, j) for name, saved in policies.items() for j, r in enumerate(saved["runs"])
             if (r["method"], json_key(r["hparams"]), r["seed"]) ==
             (record["method"], json_key(record["hparams"]), record["seed"])]
    if not found:
        raise WatchError(f"{params_dir} holds no saved policy of {method} seed {record['seed']}")
    (name, j), = found
    saved = policies[name]
    try:   # the policies' own observation (`bc-full`: the full state, in the `obs="full"` environment)
        prepared = sweep_lib.prepare(spec, sweep_lib.Hooks(log=log)).view(saved["observation"])
    except ValueError as e:
        raise WatchError(str(e)) from None
    if saved["obs_mean"] is not None and not np.allclose(saved["obs_mean"], prepared.normalizer.mean, rtol=1e-5):
        raise WatchError(f"the saved policies' observation statistics ({name}) are not those of the demonstrations: "
                         "they were trained on other data")
    from ape_jax import evaluate as evaluate_lib

    cfg = prepared.learner_config(spec.settings, saved["history"])
    runtime = evaluate_lib.runtime_of(cfg, record["method"], [record["hparams"]])  # a method's own way of acting
    policy = evaluate_lib.runtime_policy(cfg, prepared.normalizer.mean, prepared.normalizer.std, prepared.env,
                                         runtime)
    params = jax.tree.map(lambda x: x[j], saved["params"])
    env = prepared.env
    log(f"rolling out {spec.budget.eval_episodes} evaluation episodes of {method} seed {record['seed']}")
    run = jax.jit(lambda p, k: envs.rollout(env, policy, p, k, spec.budget.eval_episodes, record=env.sim_state))
    traj = jax.device_get(run(params, jax.random.PRNGKey(sweep_lib.EVAL_SEED)))
    returns = np.asarray(traj.returns)
    metric = results.main_metric
    if metric == "return":
        values = returns
    else:   # the environment's own, as the evaluation computes it
        own = jax.device_get(jax.jit(jax.vmap(env.episode_metrics))(traj.extra, traj.final, traj.valid))
        if metric not in own:
            raise WatchError(f"the environment gives no {metric!r}, the metric the sweep recorded")
        values = np.asarray(own[metric], np.float64)
    length = int(traj.lengths[episode])
    stride = max(1, math.ceil(length / max_frames))
    steps = np.arange(0, length, stride)
    sim = jax.tree.map(lambda x: np.asarray(x[episode])[steps], traj.extra)
    viewer = envs.make(spec.env, obs="image", **{**spec.env_overrides(),
                                                  **({} if spec.obs == "image" else {"image_size": tuple(size)})})
    log(f"rendering {len(steps)} frames of episode {episode} ({length} steps)")
    frames = video.render_sim_states(viewer, sim)
    label = results.label(method) + "".join(f", {k} {v:g}" if isinstance(v, (int, float)) else f", {k} {v}"
                                            for k, v in sorted(record["hparams"].items()))
    fps = max(1, min(50, round(1 / (float(env.dt) * stride))))
    return Clip(frames=frames, steps=steps, rewards=np.asarray(traj.reward[episode]),
                title=f"{label}, seed {record['seed']}, episode {episode}",
                episode_return=float(returns[episode]), mean_return=float(returns.mean()), metric=metric,
                episode_metric=float(values[episode]), mean_metric=float(values.mean()), fps=fps)


def captioned(clip: Clip, width: int = 256) -> list:
    """The clip's frames as PIL images `width` wide (nearest-neighbour scaling), each above a two-line caption:
    the title, then the step and the return so far out of the episode's (where the task is judged by another
    metric, e.g. ToyCar's success, the episode's value of that instead)."""
    from PIL import Image, ImageDraw

    scale = max(1, width // clip.frames.shape[2])
    running = np.cumsum(clip.rewards)
    out = []
    for frame, step in zip(clip.frames, clip.steps):
        image = Image.fromarray(frame)
        image = image.resize((image.width * scale, image.height * scale), Image.NEAREST)
        canvas = Image.new("RGB", (image.width, image.height + 26), "white")
        canvas.paste(image, (0, 0))
        draw = ImageDraw.Draw(canvas)
        draw.text((3, image.height + 1), clip.title, fill="black")
        progress = (f"return {running[step]:,.0f} of {clip.episode_return:,.0f}" if clip.metric == "return" else
                    f"{clip.metric} {clip.episode_metric:g}")   # e.g. ToyCar: no reward, judged by success
        draw.text((3, image.height + 13), f"step {int(step) + 1}  {progress}", fill="black")
        out.append(canvas)
    return out


def write_gif(clip: Clip, path: str | pathlib.Path, width: int = 256) -> pathlib.Path:
    """Writes the captioned clip as an animated GIF (atomically: a temporary name, then renamed), with the
    permissions of any new file (0644 under the usual umask; a `mkstemp` file would keep its 0600)."""
    path = pathlib.Path(path)
    images = captioned(clip, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, lambda f: images[0].save(f, format="GIF", save_all=True, append_images=images[1:],
                                                duration=max(1, round(1000 / clip.fps)), loop=0))
    return path
