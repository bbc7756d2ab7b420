"""The perception stage's speed on this machine: `python -m experiments.bench_perception`.

In one process, medians of `--repeats` timed calls after a compiling one (compile time apart):
  * the float32 matmul peak (the best n×n product), the ruler for every share below;
  * the encoder's embedding: frames/s of the shipped encoder's forward pass, and its share of the peak
    (2 · the network's multiply-adds per frame);
  * its pretraining: updates/s at batch 128 and their share (6 · multiply-adds per frame · batch);
  * a policy head on cached embeddings: BC-OH's updates/s on `[2 × 128]` inputs at the ToyTown `default` preset's
    batch 64, one model and the 5 seeds of a table row in one `vmap`, and their share (6 · dense weights · batch);
  * rollouts: control steps/s of ToyTown's camera, the camera through the encoder, and the one-frame state (a
    uniform-random policy reading the observation; 32 episodes × 200 steps).
Prints a Markdown table for docs/speed.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

from experiments._timing import machine, rollout_throughput, time_jitted


def _macs_per_frame(net, params, image_size) -> int:
    """Multiply-adds of one frame's forward pass: each dense kernel × the grid positions it is applied at."""
    h, w = image_size
    macs = 0
    for i, p in enumerate(net.patches):
        h, w = -(-h // p), -(-w // p)
        macs += h * w * int(np.prod(params["params"][f"patch_{i}"]["kernel"].shape))
    return macs + sum(int(np.prod(params["params"][m]["kernel"].shape)) for m in ("hidden", "embedding", "readout"))


def measure(repeats: int) -> dict:
    import envs
    from ape_jax import perception
    from ape_jax.grid import grid_runner
    from ape_jax.learner import Data, make_train
    from ape_jax.pipeline.presets import resolve
    from experiments._bench_common import matmul_peak

    out: dict = {"machine": machine()}
    peak = max(matmul_peak(repeats, sizes=(256, 512, 1024)).values())
    out["peak_gflops"] = peak / 1e9
    enc = perception.resolve("toytown", "task")
    size = tuple(enc.card["image_size"])
    macs = _macs_per_frame(enc.net, enc.params, size)
    frames = jnp.asarray(np.random.default_rng(0).integers(0, 256, (1024, *size, 3), np.uint8))
    embed = jax.jit(lambda f: enc.net.apply(enc.params, f, return_embedding=True)[1])
    compile_s, steady, _ = time_jitted(embed, frames, repeats=repeats)
    out["embed"] = {"frames_s": 1024 / steady, "compile_s": compile_s, "share": 2 * macs * 1024 / steady / peak}
    # pretraining: the update `pretrain.fit` runs, 50 in a scan
    import optax

    opt = optax.adam(1e-3)
    state = opt.init(enc.params)
    y = jnp.zeros((50, 128, enc.net.targets))
    xs = jnp.asarray(np.random.default_rng(1).integers(0, 256, (50, 128, *size, 3), np.uint8))

    @jax.jit
    def updates(params, state, xs, ys):
        def step(carry, xy):
            p, s = carry
            g = jax.grad(lambda q: jnp.mean((enc.net.apply(q, xy[0]) - xy[1]) ** 2))(p)
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), None
        return jax.lax.scan(step, (params, state), (xs, ys))[0]

    compile_s, steady, _ = time_jitted(updates, enc.params, state, xs, y, repeats=repeats)
    out["pretrain"] = {"updates_s": 50 / steady, "compile_s": compile_s,
                       "share": 6 * macs * 128 * 50 / steady / peak}
    # a policy head on cached embeddings, as the table's BC-OH trains it
    settings = resolve("toytown", "image", preset="default", sets=["recipe.perception=task"])
    iters = 1000
    cfg = settings.learner_config((enc.embedding_size,), 3, 2, "l1")
    cfg = dataclasses.replace(cfg, iterations=iters)
    learner = make_train(cfg)
    n = 20_000
    rng = np.random.default_rng(2)
    data = Data(obs=jnp.asarray(rng.normal(size=(n, enc.embedding_size)), jnp.float32),
                action=jnp.asarray(rng.uniform(size=(n, 3)), jnp.float32),
                t=jnp.asarray(np.tile(np.arange(1000), n // 1000), jnp.int32),
                ape=jnp.asarray(rng.exponential(size=n), jnp.float32))
    from ape_jax import methods
    from ape_jax.learner import stack_hparams

    weights = sum(int(np.prod(k.shape)) for k in jax.tree.leaves(
        cfg.model().init(jax.random.PRNGKey(0), jnp.zeros((1, 2 * enc.embedding_size)))) if k.ndim == 2)
    out["head"] = {"weights": weights, "batch": cfg.batch_size}
    for models in (1, 5):
        hps = stack_hparams([methods.get("bc-oh").hparams({}, settings.recipe.lr, 0)] * models)
        keys = jax.random.split(jax.random.PRNGKey(0), models)
        states = jax.jit(jax.vmap(learner.init, (0, 0, None)))(keys, hps, data)
        run = grid_runner(lambda s, hp, d: learner.run(s, hp, d, iters)[0].params, width=None)
        compile_s, steady, _ = time_jitted(run, states, hps, data, repeats=repeats)
        rate = models * iters / steady
        out["head"][models] = {"updates_s": rate, "compile_s": compile_s,
                               "share": 6 * weights * cfg.batch_size * rate / peak}
    camera = envs.make("toytown", obs="image")
    for name, env in (("camera", camera), ("camera through the encoder", perception.Perceived(camera, enc)),
                      ("one-frame state", envs.make("toytown", obs="pos"))):
        out.setdefault("rollout", {})[name] = rollout_throughput(env, 32, 200, repeats)
    return out


def table(m: dict) -> str:
    pct = lambda x: f"{100 * x:.0f}%"  # noqa: E731
    rows = [f"Machine: {m['machine']}. Float32 matmul peak: {m['peak_gflops']:.0f} GFLOP/s.", "",
            "| what | rate | compile s | share of the peak |", "|---|---:|---:|---:|",
            f"| encoder: embedding (batches of 1,024) | {m['embed']['frames_s']:,.0f} frames/s | "
            f"{m['embed']['compile_s']:.1f} | {pct(m['embed']['share'])} |",
            f"| encoder: pretraining (batch 128) | {m['pretrain']['updates_s']:,.1f} updates/s | "
            f"{m['pretrain']['compile_s']:.1f} | {pct(m['pretrain']['share'])} |"]
    for models in (1, 5):
        h = m["head"][models]
        rows.append(f"| head on embeddings: BC-OH, batch {m['head']['batch']}, {models} model(s) | "
                    f"{h['updates_s']:,.0f} model-updates/s | {h['compile_s']:.1f} | {pct(h['share'])} |")
    for name, r in m["rollout"].items():
        rows.append(f"| rollout: {name} (32 episodes × 200 steps) | {r['steps_per_s']:,.0f} steps/s | "
                    f"{r['compile_s']:.1f} | |")
    return "\n".join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.bench_perception", description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3)
    args = p.parse_args(argv)
    if args.repeats < 1:
        p.error(f"--repeats must be >= 1, got {args.repeats}")
    print(table(measure(args.repeats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
