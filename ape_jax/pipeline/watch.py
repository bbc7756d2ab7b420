"""Watching a trained policy act: one evaluation episode of a finished sweep's saved policy, as a captioned GIF.

    clip = episode_of(results.load("OUT/results.json"), "OUT/params", "bc-oh", seed=0)
    write_gif(clip, "bc-oh.gif")

The policy is rolled out exactly as the sweep evaluated it (`sweep.evaluate_group`: the same environment, the
same observation statistics and history, the same `EVAL_SEED` and number of episodes, so episode `e` here is
episode `e` of its recorded evaluation), recording the simulator's state at every step; the states are then
rendered inside `jit` by the task's renderer (`envs.video.render_sim_states`, what `experiments.collect
--preview` shows of the expert), at `size` for state observations. Each frame carries a caption: the method,
its settings and seed, the step, the task's own words for the step (`Env.caption`: a driving task's speed and
light), and the return so far out of the episode's; the last frame names the episode's outcome and is held.
`expert_episode_of` is the same episode driven by the task's expert (the same reset key), to show beside it.

The GIF plays in real time or faster (`frame_timing`): one frame per control step at the step's rate where
GIF players honour it (ToyTown's 0.1 s: 10 frames per second), every `stride`-th step where the episode
would otherwise exceed `max_frames` (the clip then plays `stride` times faster than real time).
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
      fps: the frame rate (`frame_timing`: the control step's rate, at most 50 frames per second).
      words: per frame, the task's words for its step (`Env.caption`), `{label: text}`; () where none.
      outcome: the episode's outcome in the task's words (`Env.caption`'s `"outcome"`), "" where it gives none.
      speedup: how much faster than real time the clip plays (1: real time).
      stride: the control steps between two frames (`frame_timing`).
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
    fps: float
    words: tuple[dict[str, str], ...] = ()
    outcome: str = ""
    speedup: float = 1.0
    stride: int = 1

    @property
    def frame_ms(self) -> int:
        """Each frame's display time in GIF's whole centiseconds, ms (at least 20: players slow shorter ones)."""
        return 10 * max(2, round(100 / self.fps))


MIN_FRAME_S = 0.02   # the shortest frame GIF players show as written (shorter ones are slowed to 0.1 s)
HOLD_LAST_S = 2.0    # the last frame, with the episode's outcome, stays this long


def frame_timing(dt: float, episode_length: int, max_frames: int) -> tuple[int, float, float]:
    """`(stride, fps, speedup)`: show every `stride`-th control step of `dt` seconds at `fps` frames per second.

    One frame per step at the step's own rate where GIF players honour it (a frame of at least `MIN_FRAME_S`, in
    whole centiseconds, rounded down so the clip never plays slower than real time); steps are skipped where
    that is faster (MuJoCo's 8 ms steps: every 3rd at 50 per second) or where an episode of `episode_length` steps
    would exceed `max_frames` frames. `speedup` is then the clip's speed against real time (>= 1).
    """
    if dt <= 0 or episode_length < 1 or max_frames < 1:
        raise ValueError(f"dt, episode_length and max_frames must be positive, got {dt}, {episode_length}, "
                         f"{max_frames}")
    quickest = max(1, math.ceil(MIN_FRAME_S / dt - 1e-9))   # steps per frame at the shortest frame
    centiseconds = max(round(MIN_FRAME_S * 100), math.floor(100 * dt * quickest + 1e-9))
    stride = max(quickest, math.ceil(episode_length / max_frames))
    return stride, 100 / centiseconds, stride * dt * 100 / centiseconds


EXPERT = "expert"   # `--video expert`: the task's expert on the same episode


def parse_choices(text: str) -> list[tuple[str, int | None]]:
    """`"METHOD[:SEED][,METHOD[:SEED]...]"` -> [(method, seed or None)], shown side by side; `expert` (no seed) is
    the task's expert. Raises `WatchError` for an empty or repeated choice, or a seed given to the expert."""
    choices = [parse_choice(part) for part in text.split(",")]
    if len(set(choices)) < len(choices):
        raise WatchError(f"--video {text!r}: each policy once")
    if any(method == EXPERT and seed is not None for method, seed in choices):
        raise WatchError(f"--video {text!r}: the expert has no seed; write {EXPERT}")
    return choices


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
               episode: int = 0, data_dir=None, size: tuple[int, int] = (128, 128), max_frames: int = 600,
               log: Callable[[str], None] = print) -> Clip:
    """Episode `episode` of the evaluation of `method`'s policy (`choose_run`), rendered (module docstring).

    Args:
      results, params_dir: a finished sweep's results (`results.load`) and its `params/`.
      data_dir: the demonstration cache (default: `ape_jax.pipeline.data.cache_dir()`); the observation
        statistics come from the demonstrations, collected again if missing.
      size: the frames' size for a sweep on state observations (an image sweep's frames are its own).
      max_frames: at most this many frames for an episode of the time limit's length (`frame_timing`).

    Raises:
      WatchError: no such method, seed or episode, or policies that are missing or not the sweep's.
    """
    from ape_jax.pipeline.reevaluate import spec_of

    record = choose_run(results, method, seed)
    spec = spec_of(results, data_dir)
    _check_episode(spec, episode)
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
    label = results.label(method) + "".join(f", {k} {v:g}" if isinstance(v, (int, float)) else f", {k} {v}"
                                            for k, v in sorted(record["hparams"].items()))
    log(f"rolling out {spec.budget.eval_episodes} evaluation episodes of {method} seed {record['seed']}")
    return _recorded(results, spec, prepared.env, policy, params, episode,
                     f"{label}, seed {record['seed']}, episode {episode}", size, max_frames, log)


def expert_episode_of(results: Results, episode: int = 0, data_dir=None, size: tuple[int, int] = (128, 128),
                      max_frames: int = 600, log: Callable[[str], None] = print) -> Clip:
    """Episode `episode` of the sweep's evaluation driven by the task's expert instead (its action clipped to the
    action range, as collected without noise): the same environment and reset key, so the same start, the same
    lights and traffic draws. Raises `envs.experts.ExpertError` where the sweep's expert cannot be loaded."""
    import envs
    from envs import experts
    from ape_jax.pipeline.reevaluate import spec_of

    spec = spec_of(results, data_dir)
    _check_episode(spec, episode)
    env = envs.make(spec.env, obs=spec.obs, **spec.setup.evaluation)
    act = experts.executed(spec.setup.expert.policy(env), env.action_bounds)
    policy = envs.from_observation(act, expert=True, env=env)
    log(f"rolling out {spec.budget.eval_episodes} evaluation episodes of the expert")
    return _recorded(results, spec, env, policy, None, episode, f"expert, episode {episode}", size, max_frames,
                     log)


def _check_episode(spec, episode: int) -> None:
    if not 0 <= episode < spec.budget.eval_episodes:
        raise WatchError(f"episode {episode} is not one of the evaluation's {spec.budget.eval_episodes} "
                         f"(0 to {spec.budget.eval_episodes - 1})")


def _recorded(results: Results, spec, env, policy, params, episode: int, title: str,
              size: tuple[int, int], max_frames: int, log: Callable[[str], None]) -> Clip:
    """`record_clip` of a sweep's evaluation (its environment's viewer, episodes and main metric)."""
    import envs

    viewer = envs.make(spec.env, obs="image", **{**spec.env_overrides(),
                                                  **({} if spec.obs == "image" else {"image_size": tuple(size)})})
    return record_clip(env, viewer, policy, params, episodes=spec.budget.eval_episodes, episode=episode, title=title,
                       metric=results.main_metric, max_frames=max_frames, log=log)


def record_clip(env, viewer, policy, params, *, episodes: int, episode: int, title: str, metric: str = "return",
                max_frames: int = 600, log: Callable[[str], None] = print) -> Clip:
    """Rolls out `episodes` episodes of `policy` on `env` from `EVAL_SEED` (a sweep's evaluation: episode `episode`
    is the recorded evaluation's) and returns episode `episode` as a `Clip`, rendered by `viewer` (`env`'s task
    in image mode) every `frame_timing` stride, each frame with the task's words (`viewer.caption`).

    Args:
      metric: the episode's value shown: `"return"`, or one of `env.episode_metric_names`.
    """
    import envs
    from envs import video

    run = jax.jit(lambda p, k: envs.rollout(env, policy, p, k, episodes, record=env.sim_state))
    traj = jax.device_get(run(params, jax.random.PRNGKey(sweep_lib.EVAL_SEED)))
    returns = np.asarray(traj.returns)
    own = {}
    if env.episode_metric_names:   # the environment's own metrics, as the evaluation computes them
        own = jax.device_get(jax.jit(jax.vmap(env.episode_metrics))(traj.extra, traj.final, traj.valid))
    if metric == "return":
        values = returns
    elif metric not in own:
        raise WatchError(f"the environment gives no {metric!r}, the metric the sweep recorded")
    else:
        values = np.asarray(own[metric], np.float64)
    length = int(traj.lengths[episode])
    stride, fps, speedup = frame_timing(float(env.dt), env.episode_length, max_frames)
    steps = np.arange(0, length, stride)
    sim = jax.tree.map(lambda x: np.asarray(x[episode])[steps], traj.extra)
    log(f"rendering {len(steps)} frames of episode {episode} ({length} steps)")
    frames = video.render_sim_states(viewer, sim)
    metrics = {k: float(v[episode]) for k, v in own.items()}
    at = lambda i: jax.tree.map(lambda x: x[i], sim)   # noqa: E731  one frame's simulator state
    words = tuple(viewer.caption(at(i), metrics if i == len(steps) - 1 else None) for i in range(len(steps)))
    return Clip(frames=frames, steps=steps, rewards=np.asarray(traj.reward[episode]), title=title,
                episode_return=float(returns[episode]), mean_return=float(returns.mean()), metric=metric,
                episode_metric=float(values[episode]), mean_metric=float(values.mean()), fps=fps,
                words=words if any(words) else (), outcome=words[-1].get("outcome", "") if words else "",
                speedup=speedup, stride=stride)


LINE = 13   # px per caption line (PIL's default font)


def captioned(clip: Clip, width: int = 256) -> list:
    """The clip's frames as PIL images `width` wide (nearest-neighbour scaling), each above a three-line caption:
    the title; the step and the task's words for it (`Clip.words`: a driving task's speed and light); the return
    so far out of the episode's (where the task is judged by another metric, e.g. ToyCar's success, the episode's
    value of that instead), and on the last frame the episode's outcome where the task names it."""
    from PIL import Image, ImageDraw

    scale = max(1, width // clip.frames.shape[2])
    running = np.cumsum(clip.rewards)
    out = []
    for i, (frame, step) in enumerate(zip(clip.frames, clip.steps)):
        image = Image.fromarray(frame)
        image = image.resize((image.width * scale, image.height * scale), Image.NEAREST)
        canvas = Image.new("RGB", (image.width, image.height + 3 * LINE + 2), "white")
        canvas.paste(image, (0, 0))
        draw = ImageDraw.Draw(canvas)
        words = clip.words[i] if clip.words else {}
        now = "  ".join([f"step {int(step) + 1}"] + [f"{k} {v}" for k, v in words.items() if k != "outcome"])
        progress = (f"return {running[step]:,.0f} of {clip.episode_return:,.0f}" if clip.metric == "return" else
                    f"{clip.metric} {clip.episode_metric:g}")   # e.g. ToyCar: no reward, judged by success
        if "outcome" in words:
            progress = f"outcome: {words['outcome']}"
        for row, text in enumerate((clip.title, now, progress)):
            draw.text((3, image.height + 1 + row * LINE), text, fill="black")
        out.append(canvas)
    return out


def side_by_side(clips: list[Clip], width: int = 256) -> tuple[list, list[int]]:
    """The clips' captioned frames (`captioned`) side by side, a clip that ended sooner showing its last frame;
    and each frame's display time in ms (the last held `HOLD_LAST_S`, so its outcome can be read)."""
    from PIL import Image

    panels = [captioned(clip, width) for clip in clips]
    n = max(len(p) for p in panels)
    height = max(p[0].height for p in panels)
    images = []
    for i in range(n):
        canvas = Image.new("RGB", (sum(p[0].width for p in panels) + 4 * (len(panels) - 1), height), "white")
        x = 0
        for p in panels:
            canvas.paste(p[min(i, len(p) - 1)], (x, 0))
            x += p[0].width + 4
        images.append(canvas)
    durations = [clips[0].frame_ms] * (n - 1) + [max(clips[0].frame_ms, round(HOLD_LAST_S * 1000))]
    return images, durations


def write_gif(clip: Clip | list[Clip], path: str | pathlib.Path, width: int = 256) -> pathlib.Path:
    """Writes the captioned clip (or clips, side by side: `side_by_side`) as an animated GIF at the clips' frame
    rate (the first clip's: clips of one sweep share it), atomically (a temporary name, then renamed), with the
    permissions of any new file (0644 under the usual umask; a `mkstemp` file would keep its 0600)."""
    path = pathlib.Path(path)
    images, durations = side_by_side([clip] if isinstance(clip, Clip) else list(clip), width)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, lambda f: images[0].save(f, format="GIF", save_all=True, append_images=images[1:],
                                                duration=durations if len(images) > 1 else durations[0], loop=0))
    return path
