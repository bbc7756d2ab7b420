"""Fighting Copycat Agents (FCA; Wen et al., NeurIPS 2020) as a pure-functional `Learner`: TCA, and TCA + IB.

The policy is the project's own `cfg.model()` (`StatePolicy`, FCA's BatchNorm
MLP under `network="bn-mlp"`, or an image policy), read as an encoder E, the
observation history up to the Head's 100-unit `embedding` layer (`μ`), and a
policy head F, the rest. F reads `z = μ + σ ⊙ ε`: `σ = 0` for TCA, the
information bottleneck's sample for FCA-IB (below). An adversary D reads
`[z, a_t]` and predicts the previous action `a_{t−1}`. Each iteration, on one
minibatch,

1. D takes one step on `L_D = mean_i ‖D([sg(z_i), a_t,i]) − a_{t−1,i}‖²`
   (`sg`: stop-gradient, so this step moves D only);
2. E, F (and σ) take one step on `L_BC − α · L_D + β · KL`, with the D just
   updated held fixed (`β = ib_weight`; `KL = 0` for TCA),

so E keeps what predicts `a_t` and drops what reveals `a_{t−1}` beyond what `a_t`
already does (the conditional mutual information `I(z; a_{t−1} | a_t)` that D
estimates). The trained policy is plain `cfg.model()` variables (evaluation reads
`μ`, no noise): evaluation and the loss analysis treat FCA like every other method.

    learner = make_fca(cfg)
    params, metrics = learner.train(key, FcaHparams.make(alpha=1.0, ib_weight=1e-4), data)
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, stacked_hparams, data)

Two registered methods share one compiled program (`program="fca"`), so a sweep
of both is one `vmap`:

- `fca`, "FCA (TCA)": `ib_weight = 0`, what the authors' code
  (github.com/AlvinWen428/fighting-copycat-agents) ships: its temporally
  correlated adversary without a bottleneck.
- `fca-ib`, "FCA (TCA + IB)": the paper's FCA, TCA plus a variational
  information bottleneck, at the KL weights of its `weights` (`FcaIbKnobs`,
  `--set fca-ib.weights=...`; default `DEFAULT_IB_WEIGHT`).

Each runs at each α of its `alphas` (`FcaKnobs`, `--set fca.alphas=0.1,2`), by
default the task's (`ape_jax.tasks`, `Task.fca_alpha`: the FCA code's README and
defaults, Hopper 2.0 and 1.0 elsewhere; 0.2 for the driving sandbox), with D's
learning rate `Task.fca_adversary_lr` (Hopper 4e-4, 2e-4 elsewhere) unless its
`adversary_lr` gives one (`--set fca.adversary_lr=X`).

**The information bottleneck** (FCA-IB). The embedding is a Gaussian
`N(μ(history), diag σ²)`: `μ` the `embedding` layer's output, `log σ²` a learned
per-dimension vector that does not depend on the state, kept in FCA's state
(`FcaState.log_var`), not in the policy's variables, so the policy's parameter
tree is every other method's. Training samples `z = μ + σ ⊙ ε`, `ε ~ N(0, I)`,
fed to F (`embedding_noise` of the policy's `__call__`) and to D (the paper's D
reads the bottleneck's sample), and adds
`β · mean_i KL(N(μ_i, σ²) ‖ N(0, I))`, the KL summed over the 100 dimensions.
`log σ²` starts at `LOG_VAR_INIT` (σ ≈ 0.05, small beside the embedding's
unit-scale entries at initialisation), so FCA-IB starts close to TCA and the
KL opens the bottleneck (VIB implementations start σ small for the same
reason; Alemi et al.'s demonstration code takes `softplus(x − 5)`). With `β = 0` the noise and the KL are
multiplied out exactly (`jnp.where`): TCA computes bit for bit what it would
without the bottleneck, whatever `log σ²` holds, in the same program.

**`DEFAULT_IB_WEIGHT` = 1e-4.** Neither the authors' code (no bottleneck) nor
the text available to us gives a KL weight; ours comes from the scales. The BC
loss of a trained policy on these tasks is ~0.005–0.01 (squared error summed
over action dimensions). An embedding that predicts the actions to that
precision carries some tens of nats (`½ ln(1 + SNR)` per informative
dimension, the KL summed over 100 dimensions; signal-to-noise ratios of
10²–10³ in ten to twenty dimensions give 25–70 nats). At β = 1e-4 the KL term
is then worth ~0.003–0.007, comparable to the BC loss: the bottleneck binds
without swamping it (each nat kept must pay 1e-4 of loss). β = 1e-3 would
weigh the KL ten times the BC loss, 1e-5 a tenth of it: sweep
`GridContext.ib_weights` around 1e-4 where it matters. (At the start the KL is
mostly σ's own term, ~250 nats at `LOG_VAR_INIT`: what raises σ until the
noise costs BC loss.)

**The reference predictor** R (a diagnostic, not part of the method): the
`Adversary`'s architecture fed a zero-width embedding, so it reads `a_t`
alone, trained each iteration on the same batch to predict `a_{t−1}`, with D's
optimiser and learning rate. `"reference_loss"` is what `a_t` alone says of
`a_{t−1}`; `"adversary_loss"` what `[z, a_t]` say: equal losses mean the
embedding adds nothing about the previous action beyond the current one (what
FCA aims at), `adversary_loss` below `reference_loss` means D still reads
`a_{t−1}` from the embedding.

**The recipe** decides the optimiser and the network: Adam with
`(cfg.beta1, cfg.beta2)` for every player (the FCA recipe's (0.5, 0.999), the
authors' code's), each with its own moments, learning rates `lr` (E, F and σ)
and `adversary_lr` (D and R), both on the schedule of every learner
(`ape_jax.learner.learning_rate`: ×0.1 at each of `cfg.lr_boundaries`; the
authors' code defaults to 2e-4). Under `network="bn-mlp"` training applies the
policy on batch statistics (`policy_apply(train=True)`) in both forward passes,
and the running statistics move once per iteration, as the policy objective's
pass left them.

Our readings where the paper leaves details open (or where we follow the
authors' code over the text):

- **`a_t` fed to D is the expert's action**, not the policy's prediction `F(z)`,
  as in the authors' code. The quantity to remove is `I(z; a_{t−1} | a_t)` of the
  *expert's* actions; with `F(z)` instead, the adversarial gradient would also
  reach F through D's input and push its predictions away from the expert's
  (which do carry information about `a_{t−1}`), fighting the BC loss itself.
- **Sampling**: `cfg.batch_size` rows per iteration, uniform with replacement
  over the split's rows (`Data.sample`: `Data.rows`, or every row), the
  observation history built by index exactly as in
  `ape_jax.learner.make_train`, reading whole episodes.
- **The previous action** is `data.action[history_index(data.t, idx, 1, offset=1)]`
  of the sampled rows `idx`, read from the whole episode (a split row's
  predecessor need not be in the split); at an episode start (`t = 0`) it
  repeats the first action, so there `a_{t−1} = a_t`, which D reads from its
  input: those samples (one per episode) are easy for D and carry no
  adversarial signal.
- **D** is an MLP on `concat([z, a_t])`: two hidden layers of 300 with
  LeakyReLU(0.2) (`ADVERSARY_HIDDEN`), then a linear output of `A` units; the
  same width and nonlinearity as the policy. (The authors' code uses one hidden
  layer of 300 with a LeakyReLU also on D's input; we use the two-layer MLP the
  project's spec asks for, a slightly stronger adversary.)
- **Losses**: `L_BC` is the project's BC loss (squared error summed over action
  dimensions for `"l2"`, absolute error for `"l1"`, mean over the batch, uniform
  weights); `L_D` is the squared error summed over action dimensions, mean over
  the batch, also for ToyCar's L1 policy loss. Both sums are the authors' code's
  (summed over action dimensions, averaged over the batch), so `α` means what it
  means there.
- **Step order**: D (and R) first, on the embedding of the current E, then E
  and F against the updated D, both on the same minibatch and the same `ε`, as
  in the authors' code.
- **Not reproduced**: the authors' optional Gaussian noise on the embedding
  (off by default there; the IB's learned noise is another thing).

What the game does, on toy data like that of `tests/test_fca.py` (the history
shows `a_{t−1}`, which says nothing about `a_t`; TCA, lr 1e-3, Adam (0.5,
0.999), 400 or 2000 iterations): with α = 0.5 or 1 the co-trained D stays at
chance (its loss about R's, which reads `a_t` alone) while the policy still learns
(BC loss 0.005–0.03, against 0.005–0.02 at α = 0), but a fresh D fit afterwards
on the frozen embeddings of 64 new episodes predicts `a_{t−1}` of held-out
episodes as well as for α = 0 (MSE 0.2–0.5% of chance, against 0.2–0.4%): E
keeps its D fooled rather than erasing the information. `−α · L_D` is
unbounded below: there α = 2 degraded the BC loss (0.2–0.3) and α = 5 made it
diverge.

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` the objective of
E and F (`L_BC − α · L_D + β · KL`, D after its step), `"unweighted_loss"`
`L_BC`, `"adversary_loss"` `L_D` in D's step (before its update),
`"reference_loss"` R's loss in its step (before its update), and `"kl"` the
bottleneck's KL (0 for TCA).
"""

from __future__ import annotations

import dataclasses

from typing import Any
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from ape_jax.history import history_index
from ape_jax.knobs import axis, nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, action_errors, adam_step, augment, learning_rate, make_train,
                             policy_apply, scanned_learner, trainable)
from ape_jax import methods

ADVERSARY_HIDDEN = (300, 300)
LOG_VAR_INIT = -6.0       # the bottleneck's initial log σ² in every dimension: σ ≈ 0.05
DEFAULT_IB_WEIGHT = 1e-4  # FCA-IB's KL weight β unless `fca-ib.weights` gives others (module docstring)


@dataclasses.dataclass(frozen=True)
class FcaKnobs:
    """FCA's own settings (`--set fca.KNOB=VALUE`; the module docstring).

    Attributes:
      alphas: a grid axis: the adversarial weights α to run, each finite and >= 0; empty: the task's one
        (`Task.fca_alpha`, from the FCA code's README; the supplement ran 0.1 on Hopper, 0.5 elsewhere).
      adversary_lr: the adversary's learning rate, finite and > 0; None: the task's (`Task.fca_adversary_lr`).
    """

    alphas: tuple[float, ...] = ()
    adversary_lr: float | None = None

    def __post_init__(self):
        axis("alphas", self.alphas, nonnegative, empty=True)
        if self.adversary_lr is not None:
            positive("adversary_lr", self.adversary_lr)


@dataclasses.dataclass(frozen=True)
class FcaIbKnobs(FcaKnobs):
    """FCA-IB's own settings (`--set fca-ib.KNOB=VALUE`): FCA's, and the bottleneck's KL weights.

    Attributes:
      weights: a grid axis: the KL weights β to run, each finite and >= 0; default `DEFAULT_IB_WEIGHT` (ours: the
        FCA paper gives no value for its continuous-control runs; module docstring).
    """

    weights: tuple[float, ...] = (DEFAULT_IB_WEIGHT,)

    def __post_init__(self):
        super().__post_init__()
        axis("weights", self.weights, nonnegative)


class Adversary(nn.Module):
    """D: `[..., E]` embedding and `[..., A]` current action -> `[..., A]` predicted previous action.

    With a zero-width embedding (`E = 0`) it is the reference predictor R, reading the current action alone.
    """

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
    """Traced knobs of one FCA run (stack them along a leading axis for seeds × alphas × KL weights)."""

    alpha: jax.Array         # [] float32, weight of the adversary's loss in E and F's objective
    lr: jax.Array            # [] float32, learning rate of E, F and the bottleneck's σ
    adversary_lr: jax.Array  # [] float32, learning rate of D (and of the reference predictor R)
    ib_weight: jax.Array     # [] float32, β: weight of the bottleneck's KL; 0 = TCA, no bottleneck

    @classmethod
    def make(cls, alpha: float, lr: float = 2e-4, adversary_lr: float | None = None,
             ib_weight: float = 0.0) -> FcaHparams:
        """Validated hyperparameters; `adversary_lr=None` takes `lr`."""
        adversary_lr = lr if adversary_lr is None else adversary_lr
        nonnegative("FCA alpha", alpha)
        positive("learning rate", lr)
        positive("FCA adversary learning rate", adversary_lr)
        nonnegative("FCA ib_weight", ib_weight)
        return cls(alpha=jnp.float32(alpha), lr=jnp.float32(lr), adversary_lr=jnp.float32(adversary_lr),
                   ib_weight=jnp.float32(ib_weight))


@struct.dataclass
class FcaState:
    """The scan carry: every player's parameters and Adam moments."""

    policy: Any          # cfg.model() variables (E and F; with BatchNorm's running statistics)
    adversary: Any       # Adversary parameters (D)
    reference: Any       # Adversary parameters with a zero-width embedding (R)
    log_var: jax.Array   # [E] float32, the bottleneck's log σ² (moves only when ib_weight > 0)
    policy_opt: Any      # on trainable(policy)
    adversary_opt: Any
    reference_opt: Any
    log_var_opt: Any
    step: jax.Array      # [] int32
    key: jax.Array


def make_fca(cfg: LearnerConfig) -> Learner:
    """The pure functions of FCA (TCA, and TCA + IB) for one static setup (see the module docstring).

    Args:
      cfg: shapes, counts and the recipe; `cfg.model()` is the policy (E and F),
        `cfg.loss` the BC loss, `cfg.optimizer()` every player's Adam,
        `cfg.iterations` the length of `train`.

    Returns:
      A `Learner`: `init(key, FcaHparams, Data) -> FcaState`,
      `run(state, hp, data, n) -> (state, metrics of [n] float32)`,
      `train(key, hp, data) -> (policy variables, metrics of [cfg.iterations])`,
      and `policy_input`, `per_sample_loss`, `init_policy` of `make_train(cfg)`.
    """
    base = make_train(cfg)
    model, adversary = cfg.model(), Adversary(cfg.action_dim)
    adam = cfg.optimizer()

    def init(key: jax.Array, hp: FcaHparams, data: Data) -> FcaState:
        key_policy, key_adversary, key_run, key_reference = jax.random.split(key, 4)
        policy = base.init_policy(key_policy, data)
        dummy = base.policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), data.obs.dtype))
        (_, embedding), _ = policy_apply(model, policy, dummy, return_embedding=True)
        no_action = jnp.zeros((1, cfg.action_dim), jnp.float32)
        adv = adversary.init(key_adversary, embedding, no_action)
        ref = adversary.init(key_reference, embedding[:, :0], no_action)
        log_var = jnp.full(embedding.shape[-1:], LOG_VAR_INIT, jnp.float32)
        return FcaState(policy=policy, adversary=adv, reference=ref, log_var=log_var,
                        policy_opt=adam.init(trainable(policy)), adversary_opt=adam.init(adv),
                        reference_opt=adam.init(ref), log_var_opt=adam.init(log_var),
                        step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: FcaState, hp: FcaHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        _, idx = data.sample(key_step, cfg.batch_size)
        x = base.policy_input(augment(cfg, jax.random.fold_in(key_step, 2),
                                      data.obs[history_index(data.t, idx, cfg.history)]))
        action = data.action[idx]
        previous = data.action[history_index(data.t, idx, 1, offset=1)[:, 0]]
        eps = jax.random.normal(jax.random.fold_in(key_step, 1), (cfg.batch_size,) + state.log_var.shape)
        lr, adversary_lr = learning_rate(cfg, hp.lr, state.step), learning_rate(cfg, hp.adversary_lr, state.step)
        bottleneck = hp.ib_weight > 0

        def forward(variables, log_var):
            """`(action, z, KL, variables)`; TCA: exactly no noise and no KL, whatever `log_var` holds."""
            noise = jnp.where(bottleneck, jnp.exp(0.5 * log_var) * eps, 0.0)
            (predicted, mu), variables = policy_apply(model, variables, x, train=True, return_embedding=True,
                                                      embedding_noise=noise)
            kl = 0.5 * jnp.mean(jnp.sum(mu**2 + jnp.exp(log_var) - log_var - 1.0, axis=-1))
            return predicted, mu + noise, jnp.where(bottleneck, kl, 0.0), variables

        def previous_loss(params, embedding):
            err = adversary.apply(params, embedding, action) - previous
            return jnp.mean(jnp.sum(err**2, axis=-1))

        # D's and R's steps, on the embedding of the current E (no gradient into E).
        _, z, _, _ = forward(state.policy, state.log_var)
        z = jax.lax.stop_gradient(z)
        d_loss, d_grads = jax.value_and_grad(previous_loss)(state.adversary, z)
        r_loss, r_grads = jax.value_and_grad(previous_loss)(state.reference, z[:, :0])
        adv_params, adversary_opt = adam_step(adam, state.adversary, d_grads, state.adversary_opt, adversary_lr)
        ref_params, reference_opt = adam_step(adam, state.reference, r_grads, state.reference_opt, adversary_lr)

        # E, F and σ's step against the updated D, held fixed.
        def objective(params, log_var):
            predicted, z, kl, variables = forward({**state.policy, **params}, log_var)
            bc = jnp.mean(action_errors(cfg, predicted, action))
            return bc - hp.alpha * previous_loss(adv_params, z) + hp.ib_weight * kl, (bc, kl, variables)

        (loss, (bc, kl, after)), (grads, log_var_grads) = jax.value_and_grad(objective, (0, 1), has_aux=True)(
            trainable(state.policy), state.log_var)
        params, policy_opt = adam_step(adam, trainable(state.policy), grads, state.policy_opt, lr)
        log_var, log_var_opt = adam_step(adam, state.log_var, log_var_grads, state.log_var_opt, lr)
        state = state.replace(policy={**after, **params}, adversary=adv_params, reference=ref_params,
                              log_var=log_var, policy_opt=policy_opt, adversary_opt=adversary_opt,
                              reference_opt=reference_opt, log_var_opt=log_var_opt, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "adversary_loss": d_loss, "reference_loss": r_loss,
                       "kl": kl}

    return scanned_learner(cfg, base, init, update, policy_params=lambda state: state.policy)


def _learner(ctx) -> Learner:
    return make_fca(ctx.cfg)


def _hparams(settings, lr: float, row: int) -> FcaHparams:
    return FcaHparams.make(alpha=settings["alpha"], lr=lr, adversary_lr=settings.get("adversary_lr"),
                           ib_weight=settings.get("ib_weight", 0.0))


def _runs(ctx, name: str) -> list[dict]:
    """Method `name`'s settings: each α (the task's unless given) at its adversary's learning rate."""
    knobs = ctx.knobs_of(name)
    lr = knobs.adversary_lr or ctx.task.fca_adversary_lr
    return [{"alpha": a, "adversary_lr": lr} for a in knobs.alphas or (ctx.task.fca_alpha,)]


methods.register(methods.Method(
    "fca", "FCA (TCA)", grid=lambda ctx: _runs(ctx, "fca"),
    hparams=_hparams, program="fca", learner=_learner, module=__name__, knobs=FcaKnobs))
methods.register(methods.Method(
    "fca-ib", "FCA (TCA + IB)",
    grid=lambda ctx: [{**run, "ib_weight": b} for run in _runs(ctx, "fca-ib") for b in ctx.knobs_of("fca-ib").weights],
    hparams=_hparams, program="fca", learner=_learner, module=__name__, knobs=FcaIbKnobs))
