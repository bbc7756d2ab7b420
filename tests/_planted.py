"""A planted copycat for the methods after the paper (RAP, PALR, MINE): the previous action in plain view.

The observation is `o_t = [s_t, a_{t−1}]` (`s_t` i.i.d. normal, 2-d) and the expert's action
`a_t = ρ a_{t−1} + (1 − ρ) tanh(s_t W)` (2-d, `W` fixed). With ρ = 0 (as `tests/test_fca.py`'s data) `a_{t−1}`
says nothing about `a_t` beyond the episode start, yet any history shows it: BC-OH's embedding keeps it, a
method that blocks the leak should not. With ρ > 0 the action moves smoothly and its change
`a_t − a_{t−1} = (1 − ρ)(tanh(s_t W) − a_{t−1})` is a function of the current observation, which RAP's memory
can learn.
"""

import jax.numpy as jnp
import numpy as np

from ape_jax.learner import Data

MIX = np.random.default_rng(100).normal(size=(2, 2)).astype(np.float32)


def planted(episodes: int = 16, length: int = 32, seed: int = 0, rho: float = 0.0) -> Data:
    """`episodes × length` rows, obs `[N, 4]`, actions `[N, 2]` (the module docstring)."""
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(episodes, length, 2)).astype(np.float32)
    target = np.tanh(s @ MIX)
    action = np.empty_like(target)
    action[:, 0] = target[:, 0]
    for t in range(1, length):
        action[:, t] = rho * action[:, t - 1] + (1.0 - rho) * target[:, t]
    previous = np.concatenate([action[:, :1], action[:, :-1]], axis=1)  # the first step repeats its own action
    n = episodes * length
    return Data(obs=jnp.asarray(np.concatenate([s, previous], axis=-1).reshape(n, 4)),
                action=jnp.asarray(action.reshape(n, 2)),
                t=jnp.asarray(np.tile(np.arange(length, dtype=np.int32), episodes)), ape=jnp.ones(n, jnp.float32))
