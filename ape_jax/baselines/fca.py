"""Fighting Copycat Agents (FCA; Wen et al., NeurIPS 2020) as a pure-functional `Learner`.

The policy is the project's own `cfg.model()` (`StatePolicy` or `ImagePolicy`),
read as an encoder E, the observation history up to the Head's 100-unit
`embedding` layer (`e`), and a policy head F, the rest (`F(e) -> a_t`). An
adversary D reads `[e, a_t]` and predicts the previous action `a_{t−1}`. Each
iteration, on one minibatch,

1. D takes one step on its loss `L_D = mean_i ‖D([sg(e_i), a_t,i]) − a_{t−1,i}‖²`
   (`sg`: stop-gradient, so this step moves D only);
2. E and F take one step on `L_BC − α · L_D`, with the D just updated held fixed,

so E keeps what predicts `a_t` and drops what reveals `a_{t−1}` beyond what `a_t`
already does (the conditional mutual information `I(e; a_{t−1} | a_t)` that D
estimates). The trained policy is plain `cfg.model()` parameters: evaluation and
the loss analysis treat FCA like every other method.

    learner = make_fca(cfg)
    params, metrics = learner.train(key, FcaHparams.make(alpha=0.1), data)
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, stacked_hparams, data)

`α` per task is the paper's supplement's (`ape_jax.tasks`, `Task.fca_alpha`):
Hopper 0.1, HalfCheetah and Walker2d 0.5, and 0.2 for the driving sandbox.

Our readings where the paper leaves details open (or where we follow the
authors' code, github.com/AlvinWen428/fighting-copycat-agents, over the text):

- **`a_t` fed to D is the expert's action**, not the policy's prediction `F(e)`,
  as in the authors' code. The quantity to remove is `I(e; a_{t−1} | a_t)` of the
  *expert's* actions; with `F(e)` instead, the adversarial gradient would also
  reach F through D's input and push its predictions away from the expert's
  (which do carry information about `a_{t−1}`), fighting the BC loss itself.
- **The previous action** is `data.action[history_index(data.t, idx, 1, offset=1)]`;
  at an episode start (`t = 0`) it repeats the first action, so there `a_{t−1} = a_t`,
  which D reads from its input: those samples (one per episode) are easy for D
  and carry no adversarial signal.
- **D** is an MLP on `concat([e, a_t])`: two hidden layers of 300 with
  LeakyReLU(0.2) (`ADVERSARY_HIDDEN`), then a linear output of `A` units; the
  same width and nonlinearity as the policy. (The authors' code uses one hidden
  layer of 300 with a LeakyReLU also on D's input; we use the two-layer MLP the
  project's spec asks for, a slightly stronger adversary.)
- **Losses**: `L_BC` is the project's BC loss (squared error summed over action
  dimensions for `"l2"`, absolute error for `"l1"`, mean over the batch, uniform
  weights); `L_D` is always the squared error summed over action dimensions,
  mean over the batch (the spec's `‖D − a_{t−1}‖²`), also for ToyCar's L1 policy
  loss. The authors' code averages both over action dimensions instead of summing;
  as both losses are summed here alike, `α` keeps its meaning for L2.
- **Optimisers**: Adam with betas (0.5, 0.999) for both players, each with its
  own moments, and the same learning rate `lr · 0.1^⌊step / cfg.lr_decay_every⌋`
  (the authors' code defaults to 2e-4 for both). E and F share one optimiser
  (the policy's parameter tree).
- **Step order**: D first (on the embedding of the current E), then E and F
  against the updated D, both on the same minibatch, as in the authors' code.
- **Not reproduced**: the authors' BatchNorm in E (the project's policies have
  none, so all methods share one architecture) and their optional Gaussian noise
  on `e` (off by default there).
- **Sampling**: uniform with replacement, `cfg.batch_size` rows per iteration,
  the observation history built by index exactly as in `ape_jax.learner.make_train`.

What the game does, on toy data like that of `tests/test_fca.py` (the history
shows `a_{t−1}`, which says nothing about `a_t`; lr 1e-3): with α = 0.5 or 1 the
co-trained D stays at chance while the policy still learns, but a fresh D fit
afterwards on the frozen embeddings predicts `a_{t−1}` of held-out episodes
almost as well as for α = 0 (MSE 1–2% of chance against 1%, after 400 or 2000
iterations): E keeps its D fooled rather than erasing the information.
`−α · L_D` is unbounded below; there α = 2 degraded the BC loss (0.66 against
0.001 at α = 0) and α = 5 made it diverge, E inflating the embedding.

Metrics (`[n]` per `run` of `n` iterations): `"loss"` the objective of E and F
(`L_BC − α · L_D`, D after its step), `"unweighted_loss"` `L_BC`, and
`"adversary_loss"` `L_D` in D's step (before its update).
"""

from __future__ import annotations

from typing import Any, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from ape_jax.history import history_index
from ape_jax.learner import Data, Learner, LearnerConfig, adam_step, learning_rate, make_train
from ape_jax import methods

ADVERSARY_HIDDEN = (300, 300)


class Adversary(nn.Module):
    """D: `[..., E]` embedding and `[..., A]` current action -> `[..., A]` predicted previous action."""

    action_dim: int
    hidden: Sequence[int] = ADVERSARY_HIDDEN

    @nn.compact
    def __call__(self, embedding: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([embedding, action], axis=-1)
        for i, width in enumerate(self.hidden):
            x = nn.leaky_relu(nn.Dense(width, name=f"hidden_{i}")(x), negative_slope=0.2)
        return nn.Dense(self.action_dim, name="previous_action")(x)


@struct.dataclass
class FcaHparams:
    """Traced knobs of one FCA run (stack them along a leading axis for seeds × alphas)."""

    alpha: jax.Array  # [] float32, weight of the adversary's loss in E and F's objective
    lr: jax.Array     # [] float32, learning rate of both players

    @classmethod
    def make(cls, alpha: float, lr: float = 2e-4) -> "FcaHparams":
        if not alpha >= 0.0:
            raise ValueError(f"FCA alpha must be >= 0, got {alpha}")
        if not lr > 0.0:
            raise ValueError(f"learning rate must be > 0, got {lr}")
        return cls(alpha=jnp.float32(alpha), lr=jnp.float32(lr))


@struct.dataclass
class FcaState:
    """The scan carry: both players' parameters and Adam moments."""

    policy: Any          # cfg.model() parameters (E and F)
    adversary: Any       # Adversary parameters (D)
    policy_opt: Any
    adversary_opt: Any
    step: jax.Array      # [] int32
    key: jax.Array


def make_fca(cfg: LearnerConfig) -> Learner:
    """The pure functions of FCA for one static setup (see the module docstring).

    Args:
      cfg: shapes and counts; `cfg.model()` is the policy (E and F), `cfg.loss`
        the BC loss, `cfg.iterations` the length of `train`.

    Returns:
      A `Learner`: `init(key, FcaHparams, Data) -> FcaState`,
      `run(state, hp, data, n) -> (state, metrics of [n] float32)`,
      `train(key, hp, data) -> (policy params, metrics of [cfg.iterations])`,
      and `policy_input`, `per_sample_loss` of `make_train(cfg)`.
    """
    base = make_train(cfg)
    model, adversary = cfg.model(), Adversary(cfg.action_dim)
    adam = optax.scale_by_adam(b1=0.5, b2=0.999)

    def init(key: jax.Array, hp: FcaHparams, data: Data) -> FcaState:
        if data.obs.shape[0] < cfg.batch_size:
            raise ValueError(f"the training set has {data.obs.shape[0]} samples, fewer than the batch size "
                             f"{cfg.batch_size}")
        key_policy, key_adversary, key_run = jax.random.split(key, 3)
        dummy = base.policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype))
        policy = model.init(key_policy, dummy)
        _, embedding = model.apply(policy, dummy, return_embedding=True)
        adv = adversary.init(key_adversary, embedding, jnp.zeros((1, cfg.action_dim), jnp.float32))
        return FcaState(policy=policy, adversary=adv, policy_opt=adam.init(policy), adversary_opt=adam.init(adv),
                        step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: FcaState, hp: FcaHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        idx = jax.random.randint(key_step, (cfg.batch_size,), 0, data.obs.shape[0])
        x = base.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
        action = data.action[idx]
        previous = data.action[history_index(data.t, idx, 1, offset=1)[:, 0]]
        lr = learning_rate(cfg, hp.lr, state.step)

        def adversary_loss(adv_params, embedding):
            err = adversary.apply(adv_params, embedding, action) - previous
            return jnp.mean(jnp.sum(err**2, axis=-1))

        def step(params, grads, opt_state):
            return adam_step(adam, params, grads, opt_state, lr)

        # D's step, on the embedding of the current E (no gradient into E).
        _, embedding = model.apply(state.policy, x, return_embedding=True)
        d_loss, d_grads = jax.value_and_grad(adversary_loss)(state.adversary, jax.lax.stop_gradient(embedding))
        adv_params, adversary_opt = step(state.adversary, d_grads, state.adversary_opt)

        # E and F's step against the updated D, held fixed.
        def objective(params):
            predicted, embedding = model.apply(params, x, return_embedding=True)
            err = predicted - action
            bc = jnp.mean(jnp.sum(err**2 if cfg.loss == "l2" else jnp.abs(err), axis=-1))
            return bc - hp.alpha * adversary_loss(adv_params, embedding), bc

        (loss, bc), grads = jax.value_and_grad(objective, has_aux=True)(state.policy)
        policy, policy_opt = step(state.policy, grads, state.policy_opt)
        state = state.replace(policy=policy, adversary=adv_params, policy_opt=policy_opt,
                              adversary_opt=adversary_opt, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "adversary_loss": d_loss}

    def run(state: FcaState, hp: FcaHparams, data: Data, n: int):
        return jax.lax.scan(lambda s, _: update(s, hp, data), state, None, length=n, unroll=cfg.unroll)

    def train(key: jax.Array, hp: FcaHparams, data: Data):
        state, metrics = run(init(key, hp, data), hp, data, cfg.iterations)
        return state.policy, metrics

    return Learner(init=init, run=run, train=train, policy_input=base.policy_input,
                   per_sample_loss=base.per_sample_loss, policy_params=lambda state: state.policy,
                   round_iterations=cfg.iterations)


def _learner(ctx) -> Learner:
    return make_fca(ctx.cfg)


methods.register(methods.Method(
    "fca", "FCA", grid=lambda ctx: [{"alpha": ctx.task.fca_alpha}],
    hparams=lambda settings, lr, row: FcaHparams.make(alpha=settings["alpha"], lr=lr), program="fca",
    learner=_learner, module=__name__))
