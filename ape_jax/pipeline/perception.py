"""The perception stage's pipeline part: pretraining a task's encoder, and a sweep's settings through one.

    encoder_params, card = pretrain("toytown", progress=print)     # `python -m experiments.perception`
    recipe = pinned(recipe, "toytown", "image", protocol, explicit)  # `presets.resolve`, recipe.perception set

The encoder, its file and the environment that observes through it are the core's (`ape_jax.perception`); what
needs demonstrations collected or a sweep's setup is here.

Pretraining: frames from the training layouts, their one-frame targets, one regression.

What a task declares (`ape_jax.tasks.Perception`, `Task.perception`) is all this reads; nothing here names a task:
  1. **Frames.** The task's expert drives `episodes` episodes under the declared protocol's collection settings and
     noise, and `perturbed_episodes` more with `perturbed_noise` times the protocol's noise (frames off the expert's
     path, where an imitator drifts), all in the training layouts; every `stride`-th step is kept. Each kept step's
     frame is rendered from its simulator state (`observations.observe_rows`) at the declared image size, with
     `frame_settings` (ToyTown: the speed strip lit, so the speed is a target; a frame without the speed input has
     the strip black, which reads as standing).
  2. **Targets.** The same steps observed in the declared target mode (`targets`, e.g. `pos`: what one frame shows),
     standardised with the training frames' statistics. Never the expert's actions.
  3. **Regression.** `net.PerceptionNet` by Adam on the mean squared error of the standardised targets, a cosine
     schedule, batches of `batch`; 10% of the episodes held back to report a validation loss.
  4. **Held out.** The card's `heldout`: for each declared condition (ToyTown: new layouts; new layouts and the new
     palette), `1 − R²` per target on frames of `heldout_episodes` expert episodes there: the share of the target's
     variance the encoder misses (0: read exactly; 1: no better than its mean).
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax

import envs
from ape_jax import observations, perception, tasks
from ape_jax.perception.net import PerceptionNet, in_chunks, near, net_spec, reader
from ape_jax.pipeline import collect as collect_lib
from ape_jax.pipeline import setup as setup_lib


def _env_settings(task: tasks.Task) -> tuple[setup_lib.Setup, dict]:
    """The declared protocol's setup in the target mode, and the settings every frame is made with."""
    p = task.perception
    setup = setup_lib.Setup.resolve(task.name, p.targets, task.protocol(p.protocol, p.targets))
    return setup, {**setup.collection, **dict(p.frame_settings)}


def _frames_and_targets(task: tasks.Task, settings: dict, setup: setup_lib.Setup, episodes: int, key: jax.Array,
                        noise_scale: float, log: Callable[[str], None]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                                 dict]:
    """`(frames [N, H, W, 3] uint8, targets [N, D], episode ids [N], timing)` of `episodes` expert episodes made with
    `settings`, the protocol's noise × `noise_scale`, every `stride`-th step."""
    p, proto = task.perception, setup.protocol
    env = envs.make(task.name, obs=p.targets, **settings)
    t0 = time.perf_counter()
    demos = collect_lib.collect(env, setup.expert.policy(env), key, episodes,
                                noise_frac=min(1.0, proto.noise_frac * noise_scale),
                                noise_std=proto.noise_std * noise_scale,
                                noise_steps=proto.noise_steps if proto.noise_frac > 0 else 1)
    collect_s = time.perf_counter() - t0
    keep = np.flatnonzero(np.asarray(demos.t) % p.stride == 0)
    sim = {k: np.asarray(v)[keep] for k, v in demos.sim.items()}
    image = envs.make(task.name, obs="image", **{**settings, "image_size": tuple(p.image_size)})
    frames, compile_s, render_s = observations.observe_rows(image, sim, min(4096, len(keep)))
    log(f"  {episodes} episodes, {len(keep):,} frames: collected in {collect_s:.0f} s, rendered in "
        f"{render_s:.0f} s ({len(keep) / max(render_s, 1e-9):,.0f} frames/s)")
    return (frames, np.asarray(demos.obs, np.float32)[keep], np.asarray(demos.episode)[keep],
            {"collect_s": collect_s, "render_s": render_s, "render_compile_s": compile_s})


def target_names(env: envs.Env) -> tuple[str, ...]:
    """The names of `env`'s observation's entries: its `observation_names` where it has them, else `obs[i]`."""
    names = getattr(env, "observation_names", None)
    return tuple(names) if names is not None else tuple(f"obs[{i}]" for i in range(env.observation_shape[0]))


def scores(pred: np.ndarray, target: np.ndarray, names: tuple[str, ...]) -> dict[str, float | None]:
    """`{name: 1 − R²}` per target (the mean squared error over the target's variance); None for a target that
    does not vary in these frames."""
    err = np.mean((pred - target) ** 2, axis=0)
    var = np.var(target, axis=0)
    return {n: (float(e / v) if v > 1e-12 else None) for n, e, v in zip(names, err, var, strict=True)}


def fit(net: PerceptionNet, frames: np.ndarray, targets: np.ndarray, steps: int, batch: int, lr: float,
        key: jax.Array, progress: Callable[[int, float], None] | None = None, chunk: int = 250) -> tuple[Any, list]:
    """`(params, losses per chunk)`: `net` fitted by Adam (cosine to 0 over `steps`) to the standardised `targets`
    of `frames` (on the host; each batch drawn uniformly), `chunk` updates per jitted call."""
    k_init, k_data = jax.random.split(key)
    params = net.init(k_init, frames[:1])
    opt = optax.adam(optax.cosine_decay_schedule(lr, steps))
    state = opt.init(params)

    def loss_fn(p, x, y):
        return jnp.mean((net.apply(p, x) - y) ** 2)

    @jax.jit
    def run(params, state, xs, ys):
        def step(carry, batch_xy):
            p, s = carry
            loss, grad = jax.value_and_grad(loss_fn)(p, *batch_xy)
            updates, s = opt.update(grad, s, p)
            return (optax.apply_updates(p, updates), s), loss
        (params, state), losses = jax.lax.scan(step, (params, state), (xs, ys))
        return params, state, jnp.mean(losses)

    rng = np.random.default_rng(int(jax.random.randint(k_data, (), 0, 2**31 - 1)))
    losses, done = [], 0
    while done < steps:
        n = min(chunk, steps - done)
        idx = rng.integers(0, len(frames), (n, batch))
        params, state, loss = run(params, state, frames[idx], targets[idx])
        done += n
        losses.append(float(loss))
        if progress:
            progress(done, float(loss))
    return params, losses


def pretrain(task_name: str, steps: int = 16_000, batch: int = 128, lr: float = 1e-3, seed: int = 0,
             image_size: tuple[int, int] | None = None, log: Callable[[str], None] = lambda s: None,
             progress: Callable[[int, float], None] | None = None) -> tuple[Any, dict]:
    """`(params, card)`: task `task_name`'s perception encoder trained as the module docstring says (at `image_size`
    where given, else the card's), and its card (`card.save` writes both). `ValueError` (one line) for a task that
    declares no perception card."""
    import dataclasses

    task = tasks.get(task_name)
    if task.perception is None:
        raise ValueError(f"{task_name} declares no perception card (tasks.Task.perception)")
    if image_size is not None:
        task = dataclasses.replace(task, perception=dataclasses.replace(task.perception, image_size=tuple(image_size)))
    p = task.perception
    setup, settings = _env_settings(task)
    key = jax.random.PRNGKey(seed)
    k_demo, k_off, k_held, k_fit = jax.random.split(key, 4)
    t_start = time.perf_counter()
    log(f"perception: {task_name}'s training frames ({p.protocol}, {p.image_size[0]}×{p.image_size[1]})")
    parts = [_frames_and_targets(task, settings, setup, p.episodes, k_demo, 1.0, log)]
    if p.perturbed_episodes:
        parts.append(_frames_and_targets(task, settings, setup, p.perturbed_episodes, k_off, p.perturbed_noise, log))
    frames = np.concatenate([f for f, _, _, _ in parts])
    targets = np.concatenate([y for _, y, _, _ in parts])
    episode = np.concatenate([e + 10_000 * i for i, (_, _, e, _) in enumerate(parts)])
    env_targets = envs.make(task.name, obs=p.targets, **settings)
    names = target_names(env_targets)
    scales = [p.near.get(n) for n in names]
    if unknown := sorted(set(p.near) - set(names)):
        raise ValueError(f"{task_name}'s perception card transforms {', '.join(unknown)}, which are not its targets")
    targets = np.stack([near(targets[:, i], s) if s else targets[:, i] for i, s in enumerate(scales)], axis=1)
    ids = np.unique(episode)
    val_ids = np.random.default_rng(seed).choice(ids, max(1, len(ids) // 10), replace=False)
    is_val = np.isin(episode, val_ids)
    mean, std = targets[~is_val].mean(0), targets[~is_val].std(0)
    std = np.where(std > 1e-6, std, 1.0)  # a target constant in the training frames stays on its own scale
    standard = ((targets - mean) / std).astype(np.float32)
    net = PerceptionNet(targets=len(names))
    t_fit = time.perf_counter()
    params, losses = fit(net, frames[~is_val], standard[~is_val], steps, batch, lr, k_fit, progress)
    fit_s = time.perf_counter() - t_fit
    val_loss = float(np.mean((in_chunks(lambda f: net.apply(params, f), frames[is_val]) - standard[is_val]) ** 2))
    read = lambda x: in_chunks(reader(net, params, mean, std, scales), x)  # noqa: E731 (in the targets' own units)
    heldout = {}
    for i, (name, overrides) in enumerate(p.heldout.items()):
        log(f"held out: {name}")
        f, y, _, _ = _frames_and_targets(task, {**settings, **dict(overrides)}, setup, p.heldout_episodes,
                                         jax.random.fold_in(k_held, i), 1.0, log)
        heldout[name] = scores(read(f), y, names)
    n_params = sum(int(np.size(v)) for v in jax.tree.leaves(params))
    card = {"task": task.name, "targets": list(names), "target_obs": p.targets, "image_size": list(p.image_size),
            "task_version": getattr(env_targets.config, "task_version", None),
            "palette": getattr(env_targets.config, "weather", None),
            "net": net_spec(net), "target_mean": mean.tolist(), "target_std": std.tolist(),
            "near": {n: s for n, s in zip(names, scales) if s},
            "data": {"protocol": p.protocol, "episodes": p.episodes, "perturbed_episodes": p.perturbed_episodes,
                     "perturbed_noise": p.perturbed_noise, "stride": p.stride, "frames": int(len(frames)),
                     "train_frames": int((~is_val).sum()), "val_frames": int(is_val.sum()),
                     "frame_settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.items()},
                     "heldout_episodes": p.heldout_episodes,
                     "heldout": {k: dict(v) for k, v in p.heldout.items()}},
            "training": {"steps": steps, "batch": batch, "lr": lr, "schedule": "cosine", "seed": seed,
                         "loss": "mse of the standardised targets", "parameters": n_params,
                         "final_train_loss": losses[-1], "val_loss": val_loss, "fit_s": round(fit_s, 1),
                         "frames_per_s": round(steps * batch / fit_s),
                         "collect_s": round(sum(t["collect_s"] for *_, t in parts), 1),
                         "render_s": round(sum(t["render_s"] for *_, t in parts), 1),
                         "total_s": round(time.perf_counter() - t_start, 1),
                         "hardware": f"{platform.processor() or platform.machine()}, {jax.device_count()} "
                                     f"{jax.default_backend()} device(s)",
                         "jax": jax.__version__},
            "heldout": heldout}
    return params, card


def pinned(recipe: Any, env_name: str, obs: str, protocol: Any, explicit: set[str]) -> Any:
    """`recipe` (a `presets.Recipe` with `perception` set) seeing frames through the encoder it names: the file checked
    against the sweep's camera (`check_sweep`: task, image size, task version, palette), its SHA-256 recorded, the
    pixel encoder's fields at their defaults (frozen: a state policy trains on the embeddings; `finetune`: the
    encoder "perception", `models.PerceptionPolicy`). `ValueError` (one line) for anything that does not fit;
    `explicit`: the fields `--set` gave."""
    import dataclasses

    from ape_jax.pipeline.setup import Setup

    if obs != "image":
        raise perception.PerceptionError(f"recipe.perception reads camera frames: --obs image, not --obs {obs}")
    tuned = recipe.perception_training == "finetune"
    pixels = [f"recipe.{k}" for k in ("encoder", "encoder_norm", "augment_shift") if k in explicit
              and not (tuned and k == "encoder" and recipe.encoder == "perception")]  # a replay's own words
    if pixels:
        seen = ("fine-tunes the encoder (its own image encoder, 'perception')" if tuned else
                "trains state policies on the encoder's embeddings")
        raise perception.PerceptionError(f"{', '.join(pixels)}: for policies that learn from pixels; recipe.perception "
                                         f"{recipe.perception!r} {seen}")
    if tuned and recipe.perception_output != "embedding":
        raise perception.PerceptionError(f"recipe.perception_training=finetune trains the encoder's embedding; "
                                         f"recipe.perception_output {recipe.perception_output!r} is the frozen stage's")
    encoder = perception.resolve(env_name, recipe.perception, recipe.perception_sha256)
    camera = envs.make(env_name, obs="image", **Setup.resolve(env_name, obs, protocol).collection)
    perception.check_sweep(encoder, camera)
    return dataclasses.replace(recipe, perception_sha256=encoder.sha256, encoder="perception" if tuned else "small",
                               encoder_norm="none", augment_shift=0)
