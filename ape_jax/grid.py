"""Run a function over a grid of configurations × seeds as one program, sharded over every device.

    run = grid_runner(learner.train)              # jit(vmap(train)) with the grid axis sharded
    params, metrics = run(keys, hparams, data)    # keys [G, 2], hparams leaves [G, ...]; data replicated

The grid axis is laid out over a one-axis `Mesh` of all devices (or the ones
given) with `NamedSharding`; data is replicated.

`vectorize=False` instead compiles `fn` for one configuration and runs the
configurations one after another, reusing that one executable: on CPU the
vmapped gradients of convolutions (grouped convolutions) train several times
slower per model than one model at a time, so the sweep uses it for image
policies on CPU. The grid is padded to a
multiple of the device count by repeating its last entry, and the padding is
dropped from the outputs. The same code runs on one CPU, several GPUs, or
several hosts after `jax.distributed.initialize()`; on CPU,
`XLA_FLAGS=--xla_force_host_platform_device_count=4` simulates four devices.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "grid"


def pad_grid(tree: Any, pad: int) -> Any:
    """`tree` with its leading (grid) axis extended by `pad` copies of the last entry."""
    if pad == 0:
        return tree
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)]), tree)


def grid_runner(fn: Callable[[jax.Array, Any, Any], Any], devices: Sequence[jax.Device] | None = None,
                vectorize: bool = True) -> Callable[[jax.Array, Any, Any], Any]:
    """`fn(key, hparams, data)` mapped over a grid axis, compiled once, sharded over `devices`.

    Returns:
      `run(keys, hparams, data)`: `keys [G, ...]` (or any pytree with leading
      `G`, such as a batch of training states) and every `hparams` leaf
      `[G, ...]` are split over the devices; `data` is replicated; outputs have
      leading dim `G`. A second call with the same shapes does not recompile.
    """
    if not vectorize:
        return _sequential_runner(fn)
    devices = list(devices if devices is not None else jax.devices())
    mesh = Mesh(np.array(devices), (AXIS,))
    split, replicated = NamedSharding(mesh, PartitionSpec(AXIS)), NamedSharding(mesh, PartitionSpec())
    mapped = jax.jit(jax.vmap(fn, in_axes=(0, 0, None)), in_shardings=(split, split, replicated),
                     out_shardings=split)

    def run(keys: Any, hparams: Any, data: Any) -> Any:
        g = int(jax.tree.leaves(keys)[0].shape[0])
        pad = -g % len(devices)
        out = mapped(pad_grid(keys, pad), pad_grid(hparams, pad), data)
        return jax.tree.map(lambda x: x[:g], out)

    run.devices = devices  # type: ignore[attr-defined]
    return run


def _sequential_runner(fn: Callable[[jax.Array, Any, Any], Any]) -> Callable[[jax.Array, Any, Any], Any]:
    single = jax.jit(fn)  # one executable for every configuration

    def run(keys: Any, hparams: Any, data: Any) -> Any:
        g = int(jax.tree.leaves(keys)[0].shape[0])
        outs = [single(*jax.tree.map(lambda x: x[i], (keys, hparams)), data) for i in range(g)]
        return jax.tree.map(lambda *xs: jnp.stack(xs), *outs)

    run.devices = jax.devices()[:1]  # type: ignore[attr-defined]
    return run
