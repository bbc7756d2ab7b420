"""MINE-BC: BC-OH plus a mutual information penalty estimated by a neural network (MINE: Belghazi et al., ICML
2018), the penalty baseline of PALR's paper and code (Seo et al., NeurIPS 2023), as a pure-functional `Learner`.

A statistics network `T(x, y)` gives the Donsker–Varadhan lower bound on the mutual information between the
expert's previous action and the pair (current action, policy embedding `φ`) on each minibatch (Belghazi et al.,
eq. 10, the bound their `MINE_DV` computes):

    I_DV = mean_i T(a_{t−1,i}, [a_{t,i}, φ_i]) − log mean_i exp T(a_{t−1,i}, [a_{t,π(i)}, φ_π(i)]),

`π` a random permutation of the batch (samples of the product of the marginals). Since
`I(a_{t−1}; a_t, φ) = I(a_{t−1}; a_t) + I(a_{t−1}; φ | a_t)` and the first term is the data's, lowering the bound
through `φ` lowers the conditional term PALR's HSCIC measures. Each iteration, on one minibatch, one forward and
backward pass gives both players their gradients of the same bound:

1. the policy (E and F) steps on `L_BC + weight · I_DV` (`T` as it is);
2. `T` steps up `I_DV` (`φ` as it is), then takes `inner_steps − 1` more steps on the same rows (fresh
   permutations and noise shifts).

The penalty weight is a traced knob (`MineHparams`: its `weights`, `MineKnobs`, train in one vmapped program);
weight 0 is BC-OH (the bound's gradient reaches the policy × 0; `T` still trains beside it).

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
- **One estimator step per iteration, in the policy's pass** (`INNER_STEPS` = 1), where their code follows each
  policy step with 5 estimator steps, each on a fresh batch with `φ` recomputed; and the noise is drawn once per
  iteration and shared by its passes (`draw_noise`). Their 5 steps on fresh batches would cost ~2× a BC-OH step,
  fresh noise for every pass another ~1×; as here MINE trains at ~0.7–0.8× BC-OH's updates/s (within the budget of
  1.5× its time; `experiments.bench_train --methods-only` also times 5 steps). `--set mine.steps=5` gives
  their count of steps (on the same rows), and matters: on the planted copycat of `tests/test_mine.py` one step
  leaves the embedding with as much of `a_{t−1}` as BC-OH's (the policy keeps the estimator at chance by hiding it
  below the estimator's input noise), five steps at weight 10 halve it (PALR: 30× less).
- **The loss** is the project's BC loss, not their tanh-Gaussian likelihood; the estimator's learning rate stays
  constant (theirs: no schedule at all) while the policy's follows the recipe's.
- **The previous action** at an episode's first step repeats the first action (`ape_jax.baselines._batch`).
- **Cost**: the bound reads at most `rows` rows of each minibatch (`mine.rows`, default `ESTIMATOR_ROWS`
  = 256; 0: the whole batch), as PALR's estimator does (`palr.rows`): the rows are drawn uniformly with
  replacement, so the first `rows` are a uniform subsample. Every recipe's batch up to 256 (`fca` 64, `mlp` 128)
  is read whole, so those trainings are as they were before the cap; under PALR's batch of 1,024 (recipe `mlp-b1024`)
  `T` on all 2,048 joint and marginal rows made MINE 1.5× BC-OH's time per update (docs/speed.md).

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (the policy's objective), `"unweighted_loss"` (the
BC loss), `"mi"` (the bound in the policy's step) and `"estimator_mi"` (the bound in the estimator's last step).
"""

from __future__ import annotations

import dataclasses

import itertools
from typing import Any
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from ape_jax import methods
from ape_jax.knobs import axis, integer, nonnegative, positive
from ape_jax.baselines._batch import OWN_KEYS, errors, sample_batch
from ape_jax.learner import (Data, Learner, LearnerConfig, adam_step, learning_rate, make_train, policy_apply,
                             scanned_learner, trainable)

DEFAULT_WEIGHT = 0.1        # train.py: reg_coef = 0.1 for FCA and MINE
ESTIMATOR_LR = 1e-4         # train.py: inner_lr = 1e-4 (MINE_BC's mine_lr)
INNER_STEPS = 1             # the estimator's steps per iteration (theirs: 5 on fresh batches; module docstring)
ESTIMATOR_ROWS = 256        # rows of a minibatch the bound reads (module docstring, "Cost"); 0: all
STATISTICS_HIDDEN = (100, 100)  # mine/models.py StatisticsNet
INPUT_NOISE, HIDDEN_NOISE = 0.3, 0.5


class StatisticsNetwork(nn.Module):
    """`T`: `[R, X]` and `[R, Y]` -> `[R]`, with Gaussian noise added to its input and after each hidden layer
    (MINE's `StatisticsNet`, whose noise is on in every pass). `noise` holds standard normals, one array per
    place: `[R, X + Y]`, then `[R, width]` per hidden layer (`draw_noise`)."""

    hidden: Sequence[int] = STATISTICS_HIDDEN

    @nn.compact
    def __call__(self, x: jax.Array, y: jax.Array, noise: Sequence[jax.Array]) -> jax.Array:
        h = jnp.concatenate([x, y], axis=-1) + INPUT_NOISE * noise[0]
        for i, width in enumerate(self.hidden):
            h = nn.elu(nn.Dense(width, kernel_init=nn.initializers.variance_scaling(2.0, "fan_in", "normal"),
                                name=f"hidden_{i}")(h))
            h = h + HIDDEN_NOISE * noise[i + 1]
        return nn.Dense(1, kernel_init=nn.initializers.variance_scaling(1.0, "fan_in", "normal"), name="out")(h)[..., 0]


def draw_noise(key: jax.Array, rows: int, width: int, hidden: Sequence[int] = STATISTICS_HIDDEN
               ) -> tuple[jax.Array, ...]:
    """Standard normals for `T`'s noise on `rows` rows of `width` inputs, drawn at once: `([rows, width],
    [rows, hidden_0], ...)`. One draw of a batch's rows serves an iteration's passes, joint and marginal rows
    alike (`dv_bound` rolls the rows by a random shift each time): drawing fresh noise for every pass, as the
    authors' code does, cost as much as the BC step itself on a CPU (threefry)."""
    sizes = (width, *hidden)
    z = jax.random.normal(key, (rows, sum(sizes)))
    return tuple(jnp.split(z, list(itertools.accumulate(sizes))[:-1], axis=1))


def dv_bound(network: StatisticsNetwork, params: Any, x: jax.Array, y: jax.Array, key: jax.Array,
             noise: Sequence[jax.Array]) -> jax.Array:
    """The Donsker–Varadhan bound `mean T(x, y) − log mean exp T(x, y[π])` on one batch (module docstring).

    The joint rows and the shuffled (marginal) rows go through `T` in one pass, each half's noise the rows of
    `noise` rolled by a random shift of its own.

    Args:
      network, params: `T` and its variables.
      x: `[B, X] float32` (the previous actions).
      y: `[B, Y] float32` (the current actions and the embeddings, concatenated).
      key: the permutation's and the shift's randomness.
      noise: `draw_noise(·, B, X + Y)`.

    Returns:
      `[] float32`, a lower bound on `I(x; y)` in nats (up to the estimator's fit).
    """
    b = y.shape[0]
    key_perm, key_shift = jax.random.split(key)
    shuffled = y[jax.random.permutation(key_perm, b)]
    shifts = jax.random.randint(key_shift, (2,), 0, b)
    t = network.apply(params, jnp.concatenate([x, x]), jnp.concatenate([y, shuffled]),
                      tuple(jnp.concatenate([jnp.roll(n, shifts[0], axis=0), jnp.roll(n, shifts[1], axis=0)])
                            for n in noise))
    return jnp.mean(t[:b]) - (jax.nn.logsumexp(t[b:]) - jnp.log(jnp.float32(b)))


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
        nonnegative("MINE weight", weight)
        positive("learning rate", lr)
        positive("MINE estimator learning rate", estimator_lr)
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


def make_mine(cfg: LearnerConfig, inner_steps: int = INNER_STEPS, rows: int = ESTIMATOR_ROWS) -> Learner:
    """The pure functions of MINE-BC for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe (`cfg.model()` the policy, its embedding `φ`).
      inner_steps: the estimator's steps per iteration.
      rows: the bound reads the first `min(rows, batch)` rows of each minibatch; 0: all of them.

    Returns:
      A `Learner`. `init(key)` takes its policy and run key as `make_train(cfg).init(jax.random.split(key)[0])`
      does, and the statistics network from the other half: at weight 0 its policy trains as BC-OH's from that
      key, on the same batches.
    """
    if inner_steps < 1:
        raise ValueError(f"MINE inner_steps must be >= 1, got {inner_steps}")
    if rows < 0:
        raise ValueError(f"MINE rows must be >= 0 (0: the whole batch), got {rows}")
    m = cfg.batch_size if rows == 0 else min(rows, cfg.batch_size)
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()
    network, estimator_adam = StatisticsNetwork(), optax.scale_by_adam(b1=0.9, b2=0.999)
    dummy = base.policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), jnp.float32))
    embed = jax.eval_shape(lambda: model.apply(model.init(jax.random.PRNGKey(0), dummy), dummy,
                                               return_embedding=True)[1]).shape[-1]
    width = 2 * cfg.action_dim + embed  # T reads [a_{t−1}, a_t, φ]

    def init(key: jax.Array, hp: MineHparams, data: Data) -> MineState:
        key_policy, key_statistics = jax.random.split(key)
        key_init, key_run = jax.random.split(key_policy)  # make_train's init of key_policy
        params = base.init_policy(key_init, data)
        action, joint = jnp.zeros((1, cfg.action_dim)), jnp.zeros((1, width - cfg.action_dim))
        silent = tuple(jnp.zeros((1, w)) for w in (width, *STATISTICS_HIDDEN))  # shapes only
        statistics = network.init(key_statistics, action, joint, silent)
        return MineState(params=params, opt_state=adam.init(trainable(params)), statistics=statistics,
                         statistics_opt=estimator_adam.init(statistics), step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: MineState, hp: MineHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        batch = sample_batch(cfg, base, data, key_step)
        noise = draw_noise(jax.random.fold_in(key_step, OWN_KEYS), m, width)
        lr = learning_rate(cfg, hp.lr, state.step)

        def bound(statistics, joint, j):
            return dv_bound(network, statistics, batch.previous[:m], joint[:m],
                            jax.random.fold_in(key_step, OWN_KEYS + 1 + j), noise)

        def objective(params, statistics):
            """One pass for both players: the bound's gradient reaches the policy ×weight (its descent) and T
            whole (its ascent, negated below)."""
            (predicted, embedding), variables = policy_apply(model, {**state.params, **params}, batch.x, train=True,
                                                             return_embedding=True)
            bc = jnp.mean(errors(cfg, predicted, batch.action))
            seen = jax.lax.stop_gradient(embedding)
            seen = seen + hp.weight * (embedding - seen)
            mi = bound(statistics, jnp.concatenate([batch.action, seen], axis=-1), 0)
            return bc + mi, (bc, mi, jax.lax.stop_gradient(seen), variables)

        (_, (bc, mi, embedding, after)), (grads, ascent) = jax.value_and_grad(objective, (0, 1), has_aux=True)(
            trainable(state.params), state.statistics)
        params, opt_state = adam_step(adam, trainable(state.params), grads, state.opt_state, lr)
        statistics, statistics_opt = adam_step(estimator_adam, state.statistics, jax.tree.map(jnp.negative, ascent),
                                               state.statistics_opt, hp.estimator_lr)
        joint = jnp.concatenate([batch.action, embedding], axis=-1)

        def estimator_step(carry, j):
            statistics, statistics_opt = carry
            value, ascent = jax.value_and_grad(bound)(statistics, joint, j)
            statistics, statistics_opt = adam_step(estimator_adam, statistics, jax.tree.map(jnp.negative, ascent),
                                                   statistics_opt, hp.estimator_lr)
            return (statistics, statistics_opt), value

        (statistics, statistics_opt), later = jax.lax.scan(estimator_step, (statistics, statistics_opt),
                                                           jnp.arange(1, inner_steps))
        state = state.replace(params={**after, **params}, opt_state=opt_state, statistics=statistics,
                              statistics_opt=statistics_opt, step=state.step + 1)
        return state, {"loss": bc + hp.weight * mi, "unweighted_loss": bc, "mi": mi,
                       "estimator_mi": later[-1] if inner_steps > 1 else mi}

    return scanned_learner(cfg, base, init, update)


@dataclasses.dataclass(frozen=True)
class MineKnobs:
    """MINE's own settings (`--set mine.KNOB=VALUE`; the module docstring).

    Attributes:
      weights: a grid axis: the penalty's weights, each finite and >= 0; default `DEFAULT_WEIGHT` (theirs).
      steps: the estimator's steps per iteration, >= 1; default `INNER_STEPS` (ours: theirs is 5, ~2× BC-OH's time
        per update; 1 keeps MINE within 1.5× of it).
      rows: the rows of each minibatch the bound reads; 0: the whole batch; default `ESTIMATOR_ROWS` (ours, "Cost").
    """

    weights: tuple[float, ...] = (DEFAULT_WEIGHT,)
    steps: int = INNER_STEPS
    rows: int = ESTIMATOR_ROWS

    def __post_init__(self):
        axis("weights", self.weights, nonnegative)
        integer("steps", self.steps, 1)
        integer("rows", self.rows, 0)


def _learner(ctx):
    """MINE's learner for a learner context: its estimator's steps and rows (`MineKnobs`)."""
    knobs = ctx.knobs_of("mine")
    return make_mine(ctx.cfg, knobs.steps, knobs.rows)


methods.register(methods.Method(
    "mine", "MINE", grid=lambda ctx: [{"weight": w} for w in ctx.knobs_of("mine").weights],
    hparams=lambda settings, lr, row: MineHparams.make(settings["weight"], lr=lr),
    program="mine", module=__name__, learner=_learner, knobs=MineKnobs))
