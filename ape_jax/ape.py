"""Action prediction error (APE): how unpredictable each expert action is from the expert's past actions.

The paper's definition: an MLP ψ maps the previous `k = 9` expert actions
(flattened, oldest first) to the current one, one hidden layer of 300 units
with LeakyReLU(0.2), fit with MSE on the training split (Adam, lr 1e-3, batch
512). At an episode's start the missing past actions repeat the earliest action
of the episode (at `t = 0` that is the current action itself, so the first step
of an episode has near-zero APE). Then, for every sample,

    APE_i = Σ_d (ψ(a_{i-9..i-1}) - a_i)_d²

High APE marks the expert's changepoints ("keyframes"). `normalize` divides by
the training-set mean (`"mean"`, so one τ means the same in every environment)
or leaves APE as it is (`"none"`, the original code).

    params, losses = fit(key, train.action, train.t, steps=2000)
    ape_train = errors(params, train.action, train.t)      # [N_train]
    ape_val = errors(params, val.action, val.t)            # [N_val]
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from ape_jax.history import history_index

K = 9  # past actions seen by ψ
HIDDEN = 300
NORMALIZATIONS = ("mean", "none")


class ActionPredictor(nn.Module):
    """ψ: `[..., K * A]` past actions -> `[..., A]` current action."""

    action_dim: int
    hidden: int = HIDDEN

    @nn.compact
    def __call__(self, past: jax.Array) -> jax.Array:
        x = nn.leaky_relu(nn.Dense(self.hidden)(past), negative_slope=0.2)
        return nn.Dense(self.action_dim)(x)


def past_actions(actions: jax.Array, t: jax.Array, idx: jax.Array, k: int = K) -> jax.Array:
    """ψ's input for rows `idx`: the previous `k` actions, oldest first, flattened, `[B, k * A]`."""
    rows = history_index(t, idx, k, offset=1)
    return actions[rows].reshape(idx.shape[0], -1)


def fit(key: jax.Array, actions: jax.Array, t: jax.Array, steps: int, batch: int = 512,
        lr: float = 1e-3, k: int = K, rows: jax.Array | None = None,
        count: jax.Array | int | None = None) -> tuple[dict, jax.Array]:
    """Fits ψ on a training split with MSE (jit-able; the loop is a `lax.scan`).

    Args:
      key: PRNG key (initialisation and minibatches).
      actions: expert actions, `[N, A] float32`, episodes contiguous.
      t: time index within the episode, `[N] int32`.
      steps: Adam steps.
      batch: minibatch size (sampled uniformly with replacement).
      lr: Adam learning rate.
      k: past actions per input.
      rows: `[N'] int32`, the training rows among `actions` (a split by rows: the past actions still come from
        the whole episodes); None: every row.
      count: minibatches are drawn from the first `count` rows (of `rows`, or of `actions`) only; the rest is
        padding, so arrays of one shape can hold datasets of different sizes (traced: one compiled fit for
        all). None: every row.

    Returns:
      (params, losses): ψ's parameters and the per-step minibatch MSE `[steps]`.
    """
    actions = jnp.asarray(actions, jnp.float32)
    a = actions.shape[1]
    n = actions.shape[0] if rows is None else rows.shape[0]
    n = n if count is None else count
    model = ActionPredictor(a)
    key_init, key_batches = jax.random.split(key)
    params = model.init(key_init, jnp.zeros((1, k * a)))
    opt = optax.adam(lr)

    def loss_fn(p, idx):
        pred = model.apply(p, past_actions(actions, t, idx, k))
        return jnp.mean(jnp.sum((pred - actions[idx]) ** 2, axis=-1))

    def update(carry, step):
        p, s = carry
        idx = jax.random.randint(jax.random.fold_in(key_batches, step), (batch,), 0, n)
        idx = idx if rows is None else rows[idx]
        loss, grads = jax.value_and_grad(loss_fn)(p, idx)
        updates, s = opt.update(grads, s, p)
        return (optax.apply_updates(p, updates), s), loss

    (params, _), losses = jax.lax.scan(update, (params, opt.init(params)), jnp.arange(steps))
    return params, losses


def errors(params: dict, actions: jax.Array, t: jax.Array, k: int = K) -> jax.Array:
    """Per-sample APE `[N] float32` of every row of a dataset (training or validation)."""
    actions = jnp.asarray(actions, jnp.float32)
    model = ActionPredictor(actions.shape[1])
    pred = model.apply(params, past_actions(actions, t, jnp.arange(actions.shape[0]), k))
    return jnp.sum((pred - actions) ** 2, axis=-1)


def normalize(ape_train: jax.Array, ape_val: jax.Array, mode: str = "mean") -> tuple[jax.Array, jax.Array, float]:
    """Divides both splits' APE by the training mean (`"mean"`) or not at all (`"none"`).

    Returns:
      (ape_train, ape_val, scale): the divisor used (1.0 for `"none"`).
    """
    if mode not in NORMALIZATIONS:
        raise ValueError(f"unknown APE normalization {mode!r}; valid: {list(NORMALIZATIONS)}")
    scale = float(jnp.mean(ape_train)) if mode == "mean" else 1.0
    if not scale > 0:
        raise ValueError(f"APE normalization: the training-set mean APE is {scale}; the expert's actions "
                         "are perfectly predictable, so APE cannot rank samples (use 'none')")
    return ape_train / scale, ape_val / scale, scale


def fit_all(actions, t, steps: int, seed: int = 0, bar=None):
    """Raw APE `[N]` (numpy) of every sample of a dataset, from ψ fitted on all of it.

    For the entry points that weight or picture a whole dataset (the sweep fits
    on its training split only). `bar`: a tqdm-like progress bar, kept ticking
    while the fit (one asynchronous scan) runs. APE is computed in chunks of
    whole episodes (ψ sees past actions within an episode only, so the values
    are exact) to bound memory.
    """
    import functools
    import time

    import numpy as np

    actions, t = jnp.asarray(actions, jnp.float32), jnp.asarray(t)
    params, losses = jax.jit(functools.partial(fit, steps=steps))(jax.random.PRNGKey(seed), actions, t)
    while bar is not None and not losses.is_ready():
        bar.update(0)
        time.sleep(0.2)
    if bar is not None:
        bar.update(steps)
    starts = np.flatnonzero(np.asarray(t) == 0)
    cuts = [0]
    for s in starts[1:]:
        if s - cuts[-1] >= 1 << 16:
            cuts.append(int(s))
    cuts.append(len(actions))
    return np.concatenate([np.asarray(errors(params, actions[a:b], t[a:b])) for a, b in zip(cuts, cuts[1:])])

