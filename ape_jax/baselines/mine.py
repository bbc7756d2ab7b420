"""MINE-BC: BC-OH plus a mutual information penalty estimated by a neural network (MINE: Belghazi et al., ICML
2018), the penalty baseline of PALR's paper and code (Seo et al., NeurIPS 2023), as a pure-functional `Learner`.

A statistics network `T(x, y)` gives the Donsker–Varadhan lower bound on the mutual information between the
expert's previous action and the pair (current action, policy embedding `φ`) on each minibatch (Belghazi et al.,
eq. 10, the bound their `MINE_DV` computes):

    I_DV = mean_i T(a_{t−1,i}, [a_{t,i}, φ_i]) − log mean_i exp T(a_{t−1,i}, [a_{t,π(i)}, φ_π(i)]),

`π` a random permutation of the batch (samples of the product of the marginals). Since
`I(a_{t−1}; a_t, φ) = I(a_{t−1}; a_t) + I(a_{t−1}; φ | a_t)` and the first term is the data's, lowering the bound
through `φ` lowers the conditional term PALR's HSCIC measures. Each iteration, on one minibatch,

1. the policy (E and F) takes one step on `L_BC + weight · I_DV` with `T` held fixed;
2. `T` takes `INNER_STEPS` steps maximising `I_DV` on the same rows, `φ` held fixed (fresh permutations and
   noise each step),

the order of the authors' code (policy first, then the estimator). The penalty weight is a traced knob
(`MineHparams`: the recipe's `mine_weights` train in one vmapped program); weight 0 is BC-OH (the policy's
step then ignores `T`, which still trains beside it).

Defaults as in the authors' code (`github.com/KAIST-AILab/palr`): weight 0.1 (`train.py`: MINE runs at
`reg_coef = 0.1`), the estimator's Adam at learning rate 1e-4 with PyTorch's default moments (0.9, 0.999)
(`imitation/mine.py`: `mine_lr = inner_lr`), no information-bottleneck term (`ib_coef = 0` but for FCA), and their
`StatisticsNet` (`mine/models.py`): `[x, y]` plus Gaussian noise of std 0.3, two hidden layers of 100 with ELU,
each followed by Gaussian noise of std 0.5 (in every pass, as their `forward` does), a linear output; Kaiming-normal
kernels (ReLU gain for the hidden layers, linear for the output) and zero biases. Actions as they are (their MINE
does not standardise them).

Our readings:

- **No moving-average gradient correction.** Their `MINE_DV` has the bias-corrected gradient (an exponential
  moving average of `mean exp T` in the denominator), but it turns on only once `step_epoch` has been called
  past its anneal period, and their BC training never calls it: the bound they train with is the plain
  (biased-gradient) one above, and so is ours.
- **The estimator's steps reuse the policy step's rows and embeddings** (computed before the policy's update),
  where their code draws a fresh batch and recomputes `φ` for each of its 5 inner steps. Those 5 extra policy
  forward passes would cost ~2× a BC-OH step; `INNER_STEPS` steps of `T` on the batch's embeddings cost ~0.3×
  (`experiments.bench_train`), so MINE stays within 1.5× of BC-OH's updates/s.
- **The loss** is the project's BC loss, not their tanh-Gaussian likelihood; the estimator's learning rate stays
  constant (theirs: no schedule at all) while the policy's follows the recipe's.
- **The previous action** at an episode's first step repeats the first action (`ape_jax.baselines._batch`).

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (the policy's objective), `"unweighted_loss"` (the
BC loss), `"mi"` (the bound in the policy's step) and `"estimator_mi"` (the bound in the estimator's last step).
"""

from __future__ import annotations

from typing import Any
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from ape_jax import methods
from ape_jax.baselines._batch import OWN_KEYS, errors, sample_batch
from ape_jax.learner import (Data, Learner, LearnerConfig, adam_step, gradient_step, learning_rate, make_train,
                             policy_apply, trainable)

DEFAULT_WEIGHT = 0.1        # train.py: reg_coef = 0.1 for FCA and MINE
ESTIMATOR_LR = 1e-4         # train.py: inner_lr = 1e-4 (MINE_BC's mine_lr)
INNER_STEPS = 2             # the estimator's steps per iteration (theirs: 5 on fresh batches; module docstring)
STATISTICS_HIDDEN = (100, 100)  # mine/models.py StatisticsNet
INPUT_NOISE, HIDDEN_NOISE = 0.3, 0.5


class StatisticsNetwork(nn.Module):
    """`T`: `[B, X]` and `[B, Y]` -> `[B]`, with Gaussian noise on its input and after each hidden layer (the
    `"noise"` rng: MINE's `StatisticsNet`, whose noise is on in every pass)."""

    hidden: Sequence[int] = STATISTICS_HIDDEN

    @nn.compact
    def __call__(self, x: jax.Array, y: jax.Array) -> jax.Array:
        h = jnp.concatenate([x, y], axis=-1)
        h = h + INPUT_NOISE * jax.random.normal(self.make_rng("noise"), h.shape)
        for i, width in enumerate(self.hidden):
            h = nn.elu(nn.Dense(width, kernel_init=nn.initializers.variance_scaling(2.0, "fan_in", "normal"),
                                name=f"hidden_{i}")(h))
            h = h + HIDDEN_NOISE * jax.random.normal(self.make_rng("noise"), h.shape)
        return nn.Dense(1, kernel_init=nn.initializers.variance_scaling(1.0, "fan_in", "normal"), name="out")(h)[..., 0]


def dv_bound(network: StatisticsNetwork, params: Any, x: jax.Array, y: jax.Array, key: jax.Array) -> jax.Array:
    """The Donsker–Varadhan bound `mean T(x, y) − log mean exp T(x, y[π])` on one batch (module docstring).

    Args:
      network, params: `T` and its variables.
      x: `[B, X] float32` (the previous actions).
      y: `[B, Y] float32` (the current actions and the embeddings, concatenated).
      key: the permutation's and the noise's randomness.

    Returns:
      `[] float32`, a lower bound on `I(x; y)` in nats (up to the estimator's fit).
    """
    key_perm, key_joint, key_marginal = jax.random.split(key, 3)
    shuffled = y[jax.random.permutation(key_perm, y.shape[0])]
    joint = network.apply(params, x, y, rngs={"noise": key_joint})
    marginal = network.apply(params, x, shuffled, rngs={"noise": key_marginal})
    return jnp.mean(joint) - (jax.nn.logsumexp(marginal) - jnp.log(jnp.float32(y.shape[0])))


@struct.dataclass
class MineHparams:
    """Traced knobs of one MINE-BC run (stack them along a leading axis for seeds × weights)."""

    weight: jax.Array        # [] float32, the MI penalty's weight; 0 = BC-OH
    lr: jax.Array            # [] float32, the policy's learning rate
    estimator_lr: jax.Array  # [] float32, T's

    @classmethod
    def make(cls, weight: float = DEFAULT_WEIGHT, lr: float = 2e-4, estimator_lr: float = ESTIMATOR_LR
             ) -> MineHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        if not 0.0 <= weight < float("inf"):
            raise ValueError(f"MINE weight must be >= 0 and finite, got {weight}")
        for name, value in (("learning rate", lr), ("MINE estimator learning rate", estimator_lr)):
            if not 0.0 < value < float("inf"):
                raise ValueError(f"{name} must be > 0, got {value}")
        return cls(weight=jnp.float32(weight), lr=jnp.float32(lr), estimator_lr=jnp.float32(estimator_lr))


@struct.dataclass
class MineState:
    """The scan carry: the policy's variables and moments (as BC-OH's), and the statistics network's."""

    params: Any          # cfg.model() variables
    opt_state: Any       # on trainable(params)
    statistics: Any      # StatisticsNetwork variables
    statistics_opt: Any
    step: jax.Array      # [] int32
    key: jax.Array


def make_mine(cfg: LearnerConfig, inner_steps: int = INNER_STEPS) -> Learner:
    """The pure functions of MINE-BC for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe (`cfg.model()` the policy, its embedding `φ`).
      inner_steps: the estimator's steps per iteration.

    Returns:
      A `Learner`. `init(key)` takes its policy and run key as `make_train(cfg).init(jax.random.split(key)[0])`
      does, and the statistics network from the other half: at weight 0 its policy trains as BC-OH's from that
      key, on the same batches.
    """
    if inner_steps < 1:
        raise ValueError(f"MINE inner_steps must be >= 1, got {inner_steps}")
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()
    network, estimator_adam = StatisticsNetwork(), optax.scale_by_adam(b1=0.9, b2=0.999)

    def init(key: jax.Array, hp: MineHparams, data: Data) -> MineState:
        key_policy, key_statistics = jax.random.split(key)
        key_init, key_run = jax.random.split(key_policy)  # make_train's init of key_policy
        params = base.init_policy(key_init, data)
        dummy = base.policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype))
        (_, embedding), _ = policy_apply(model, params, dummy, return_embedding=True)
        action = jnp.zeros((1, cfg.action_dim), jnp.float32)
        key_params, key_noise = jax.random.split(key_statistics)
        statistics = network.init({"params": key_params, "noise": key_noise}, action,
                                  jnp.concatenate([action, embedding], axis=-1))
        return MineState(params=params, opt_state=adam.init(trainable(params)), statistics=statistics,
                         statistics_opt=estimator_adam.init(statistics), step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: MineState, hp: MineHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        batch = sample_batch(cfg, base, data, key_step)
        key_policy = jax.random.fold_in(key_step, OWN_KEYS)

        def loss_fn(variables):
            (predicted, embedding), variables = policy_apply(model, variables, batch.x, train=True,
                                                             return_embedding=True)
            bc = jnp.mean(errors(cfg, predicted, batch.action))
            joint = jnp.concatenate([batch.action, embedding], axis=-1)
            mi = dv_bound(network, state.statistics, batch.previous, joint, key_policy)
            return bc + hp.weight * mi, ((bc, mi, joint), variables)

        params, opt_state, loss, (bc, mi, joint) = gradient_step(
            adam, state.params, state.opt_state, learning_rate(cfg, hp.lr, state.step), loss_fn)
        joint = jax.lax.stop_gradient(joint)

        def estimator_step(carry, j):
            statistics, statistics_opt = carry
            key = jax.random.fold_in(key_step, OWN_KEYS + 1 + j)
            bound, grads = jax.value_and_grad(lambda p: dv_bound(network, p, batch.previous, joint, key))(statistics)
            grads = jax.tree.map(jnp.negative, grads)  # ascent on the bound
            statistics, statistics_opt = adam_step(estimator_adam, statistics, grads, statistics_opt,
                                                   hp.estimator_lr)
            return (statistics, statistics_opt), bound

        (statistics, statistics_opt), bounds = jax.lax.scan(
            estimator_step, (state.statistics, state.statistics_opt), jnp.arange(inner_steps))
        state = state.replace(params=params, opt_state=opt_state, statistics=statistics,
                              statistics_opt=statistics_opt, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "mi": mi, "estimator_mi": bounds[-1]}

    def run(state: MineState, hp: MineHparams, data: Data, n: int):
        return jax.lax.scan(lambda s, _: update(s, hp, data), state, None, length=n, unroll=cfg.unroll)

    def train(key: jax.Array, hp: MineHparams, data: Data):
        state, metrics = run(init(key, hp, data), hp, data, cfg.iterations)
        return state.params, metrics

    return Learner(init=init, run=run, train=train, policy_input=base.policy_input,
                   per_sample_loss=base.per_sample_loss, round_iterations=cfg.iterations,
                   init_policy=base.init_policy)


def _grid(ctx) -> list[dict]:
    recipe = getattr(ctx, "recipe", None)
    weights = (recipe.mine_weights if recipe is not None else ()) or (DEFAULT_WEIGHT,)
    return [{"weight": w} for w in weights]


methods.register(methods.Method(
    "mine", "MINE", grid=_grid, hparams=lambda settings, lr, row: MineHparams.make(settings["weight"], lr=lr),
    program="mine", learner=lambda ctx: make_mine(ctx.cfg), module=__name__))
