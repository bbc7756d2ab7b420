"""What the benchmarks share (`experiments.bench_train`, its `--share` part `experiments._share`, the device
measurements): the benchmark's shapes (Hopper `pos`: input 2 × 5, action 3, batch 128), its synthetic data, the
dense weights of a learner's network, a recipe's learner on those shapes, and the float32 matmul peak.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ape_jax.learner import Data, LearnerConfig
from ape_jax.pipeline.presets import resolve
from experiments._timing import time_jitted

OBS, ACT, H, BATCH = 5, 3, 2, 128


def _data(n=20_000, seed=0) -> Data:
    rng = np.random.default_rng(seed)
    return Data(obs=jnp.asarray(rng.normal(size=(n, OBS)), jnp.float32),
                action=jnp.asarray(np.tanh(rng.normal(size=(n, ACT))), jnp.float32),
                t=jnp.asarray(np.tile(np.arange(1000), n // 1000), jnp.int32),
                ape=jnp.asarray(rng.exponential(size=n), jnp.float32))


def macs_per_sample(cfg: LearnerConfig) -> int:
    params = cfg.model().init(jax.random.PRNGKey(0), jnp.zeros((1, cfg.history * cfg.obs_shape[0])))
    return int(sum(np.prod(k.shape) for k in jax.tree.leaves(params) if k.ndim == 2))


def recipe_config(recipe: str, iters: int) -> LearnerConfig:
    """The learner of recipe `recipe` on the benchmark's shapes (Hopper `pos`, history 2), `iters` iterations."""
    settings = resolve("hopper", "pos", recipe=recipe, sets=[f"budget.iterations={iters}"])
    return settings.learner_config((OBS,), ACT, H, "l2")


def matmul_peak(repeats: int, sizes: tuple[int, ...] = (256, 512, 1024, 2048), dtype=jnp.float32) -> dict[int, float]:
    """FLOP/s of one `n×n @ n×n` product in `dtype` (2n³ operations) per size `n`: medians after a compiling call."""
    out = {}
    for n in sizes:
        a = jax.random.normal(jax.random.PRNGKey(0), (n, n), jnp.float32).astype(dtype)
        _, steady, _ = time_jitted(jax.jit(lambda x: x @ x), a, repeats=repeats)
        out[n] = 2 * n**3 / steady
    return out
