"""Run a function over a grid of configurations × seeds as one program, sharded over every device.

    run = grid_runner(learner.train)              # jit(vmap(train)) with the grid axis sharded
    params, metrics = run(keys, hparams, data)    # keys [G, 2], hparams leaves [G, ...]; data replicated

The grid axis is laid out over a one-axis `Mesh` of all devices (or the ones
given) with `NamedSharding`; data is replicated.

Several processes (`jax.distributed.initialize()`, one per host, all running
the same program): `jax.devices()` is then every process's devices, and the
mesh spans them all. Every process holds the whole grid and the data on its
host and gives its own devices their rows (`jax.make_array_from_callback`);
the outputs come back to every process's host, whole, as NumPy arrays (the
training program is the one a single process with as many devices compiles;
the gather is a program of its own). Every process must make the same calls
in the same order: each call is a collective.

`width=W` gives every configuration the same program whatever else runs
beside it: the grid is cut into blocks of `W` configurations per device, the
last padded, and one executable of that shape runs block after block. XLA
rounds a vmapped batch of another size differently (a 12- and a 20-run
program gave the same Hopper seed weights 0.16 apart after 30,000 updates),
so only a fixed width makes a configuration's numbers independent of the
sweep it is in. `width=None`: the whole grid in one call (the sweep's way
before `Budget.width`). On a CPU width 1 costs little in training (one
`bench_train` run: 0.92-1.30x the whole 13-run grid's updates/s) and more in
evaluation (0.59x the env steps/s at 8 episodes per policy; docs/reliability.md).

`vectorize=False` instead compiles `fn` for one configuration and runs the
configurations one after another, reusing that one executable: on CPU the
vmapped gradients of convolutions (grouped convolutions) train several times
slower per model than one model at a time, so the sweep uses it for image
policies on CPU (with several processes, each runs every configuration on its
own first device: nothing is shared, nothing is faster). The grid is padded to a
multiple of the device count by repeating its last entry, and the padding is
dropped from the outputs. The same code runs on one CPU, several GPUs, or
several processes or hosts after `jax.distributed.initialize()`; on CPU,
`XLA_FLAGS=--xla_force_host_platform_device_count=4` simulates four devices.
"""

from __future__ import annotations

import zlib
from typing import Any
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "grid"


def pad_grid(tree: Any, pad: int) -> Any:
    """`tree` with its leading (grid) axis extended by `pad` copies of the last entry."""
    if pad == 0:
        return tree
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)]), tree)


def in_blocks(mapped: Callable[..., Any], width: int | None, n_mapped: int = 1) -> Callable[..., Any]:
    """`mapped(*args)` called on blocks of exactly `width` entries of the leading axis of its first `n_mapped`
    arguments (pytrees), the last block padded by repeating its last entry; the outputs' leading axes are joined
    and the padding dropped. The other arguments go to every call whole. `width=None`: one call on everything.

    With `mapped` a jitted vmap, every entry is then computed by the same executable whatever the leading size,
    so its result does not depend on how many entries run beside it (module docstring).
    """
    if width is not None and width < 1:
        raise ValueError(f"in_blocks: width must be >= 1 or None, got {width}")

    def run(*args: Any) -> Any:
        grid, rest = args[:n_mapped], args[n_mapped:]
        g = int(jax.tree.leaves(grid)[0].shape[0])
        if width is None:
            return mapped(*grid, *rest)
        outs = []
        for start in range(0, g, width):
            block = jax.tree.map(lambda x: x[start:start + width], grid)
            outs.append(mapped(*pad_grid(block, width - min(width, g - start)), *rest))
        join = np.concatenate if isinstance(jax.tree.leaves(outs[0])[0], np.ndarray) else jnp.concatenate
        return jax.tree.map(lambda *xs: join(xs)[:g], *outs)

    return run


def grid_runner(fn: Callable[[jax.Array, Any, Any], Any], devices: Sequence[jax.Device] | None = None,
                vectorize: bool = True, width: int | None = None) -> Callable[[jax.Array, Any, Any], Any]:
    """`fn(key, hparams, data)` mapped over a grid axis, compiled once, sharded over `devices`.

    Returns:
      `run(keys, hparams, data)`: `keys [G, ...]` (or any pytree with leading
      `G`, such as a batch of training states) and every `hparams` leaf
      `[G, ...]` are split over the devices; `data` is replicated; outputs have
      leading dim `G`. A second call with the same shapes does not recompile.
      When `devices` span several processes, inputs may be NumPy or
      process-local arrays (each process passes the whole grid) and outputs
      are NumPy arrays, whole on every process. With `width`, the grid runs in blocks of `width` configurations
      per device (`in_blocks`), so a configuration's outputs do not depend on `G`.
    """
    if not vectorize:
        return _sequential_runner(fn)
    devices = list(devices if devices is not None else jax.devices())
    mesh = Mesh(np.array(devices), (AXIS,))
    split, replicated = NamedSharding(mesh, PartitionSpec(AXIS)), NamedSharding(mesh, PartitionSpec())
    mapped = jax.jit(jax.vmap(fn, in_axes=(0, 0, None)), in_shardings=(split, split, replicated),
                     out_shardings=split)

    several = len({d.process_index for d in devices}) > 1
    # one program gathers the whole output tree (`process_allgather` compiles one per leaf)
    gather = jax.jit(lambda tree: tree, out_shardings=replicated) if several else None

    def whole(keys: Any, hparams: Any, data: Any) -> Any:
        g = int(jax.tree.leaves(keys)[0].shape[0])
        pad = -g % len(devices)
        args = pad_grid(keys, pad), pad_grid(hparams, pad), data
        if not several:
            out = mapped(*args)
        else:  # a jit refuses host arrays for a mesh of several processes: each process fills its own devices
            out = jax.tree.map(np.asarray, gather(mapped(*(
                global_array(a, s) for a, s in zip(args, (split, split, replicated))))))
        return jax.tree.map(lambda x: x[:g], out)

    run = in_blocks(whole, None if width is None else width * len(devices), n_mapped=2)
    run.devices = devices  # type: ignore[attr-defined]
    run.width = width  # type: ignore[attr-defined]
    return run


def global_array(tree: Any, sharding: NamedSharding) -> Any:
    """`tree` (leaves the same on every process's host) as global arrays laid out by `sharding`.

    Each process copies only the slices its own devices hold. Leaves keep their
    shapes and dtypes; they must be the same on every process.
    """
    def one(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(one, tree)


def from_process_zero(tree: Any) -> Any:
    """`tree` as process 0 holds it, on every process, bit for bit (NumPy leaves).

    Every process must call it, with a tree of the same structure, shapes and
    dtypes (the values of the others are ignored). One process: `tree` as it is.
    """
    if jax.process_count() == 1:
        return tree
    leaves, treedef = jax.tree.flatten(tree)
    leaves = [np.asarray(x) for x in leaves]
    # `broadcast_one_to_all` adds zeros from the other processes: done on the bytes, that is exact for every
    # dtype (floats would lose the sign of -0.0) and keeps 64-bit values intact without jax_enable_x64
    sent = multihost_utils.broadcast_one_to_all([np.ascontiguousarray(x).reshape(-1).view(np.uint8) for x in leaves])
    return jax.tree.unflatten(treedef, [np.asarray(b).view(x.dtype).reshape(x.shape) for b, x in zip(sent, leaves)])


def differing_processes(tree: Any) -> list[int]:
    """The processes whose `tree` differs from process 0's; `[]` in a one-process run.

    Compares one CRC-32 per process of the tree's structure, shapes, dtypes and
    bytes. Every process must call it.
    """
    if jax.process_count() == 1:
        return []
    leaves, treedef = jax.tree.flatten(tree)
    crc = zlib.crc32(str(treedef).encode())
    for x in map(np.asarray, leaves):
        crc = zlib.crc32(np.ascontiguousarray(x), zlib.crc32(f"{x.dtype}{x.shape}".encode(), crc))
    every = np.asarray(multihost_utils.process_allgather(np.array([crc], np.uint32))).reshape(-1)
    return [i for i, c in enumerate(every) if c != every[0]]


def _sequential_runner(fn: Callable[[jax.Array, Any, Any], Any]) -> Callable[[jax.Array, Any, Any], Any]:
    single = jax.jit(fn)  # one executable for every configuration

    def run(keys: Any, hparams: Any, data: Any) -> Any:
        g = int(jax.tree.leaves(keys)[0].shape[0])
        outs = [single(*jax.tree.map(lambda x: x[i], (keys, hparams)), data) for i in range(g)]
        return jax.tree.map(lambda *xs: jnp.stack(xs), *outs)

    run.devices = jax.devices()[:1]  # type: ignore[attr-defined]
    run.width = 1  # type: ignore[attr-defined]
    return run
