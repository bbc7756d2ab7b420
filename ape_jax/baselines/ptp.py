"""PTP, past-token prediction (Torne, Tang, Liu and Finn, 2025, "Learning Long-Context Robot Policies via Past-Token
Prediction"; arXiv 2505.09561, "Learning Long-Context Diffusion Policies via Past-Token Prediction"), as a
pure-functional `Learner`.

The paper finds the opposite of the copycat problem in recent (diffusion) policies: given a long context they fail
to keep the dependence between past and future actions. Its remedy (its method section, the PTP objective
`â_{t−k:t+l} = π_θ(o_{t−k:t})`) is an auxiliary task: from the observations `o_{t−k..t}` the policy predicts the
past actions `a_{t−k..t−1}` as well as the current and future ones, every token in one output sequence under the
policy's loss. Here an auxiliary head `P` on the policy's embedding `φ` (the Head's 100-unit `embedding` layer,
which every state and image policy returns with `return_embedding=True`) predicts the `k = past` previous actions,
oldest first, beside the policy's own action:

    L = mean_i ℓ(π(o_{t−H+1..t}), a_t) + weight · mean_i mean_j ℓ(P(φ)_j, a_{t−k−1+j}),   j = 1..k,

`ℓ` the project's per-sample loss (`learner.action_errors`: squared error summed over action dimensions, or the
task's weighted absolute error). The policy steps on `L`; `P` steps on the past term alone at full weight (a
stop-gradient mixes `weight` into what reaches `φ`), so `P` keeps learning at weight 0 and `"past_loss"` is then
a probe of how much of the past BC-OH's embedding holds. At weight 0 the policy is BC-OH's: `init(key)` draws it
and the run key as `make_train(cfg).init(jax.random.split(key)[0])` does (MINE's convention; `P` from the other
half), on BC-OH's batches (`_batch.sample_batch`), with BC-OH's loss and updates. The trained policy is a plain
`cfg.model()` (`P` lives beside it, as RAP's residual head does), so evaluation, the loss analysis, the probes and
checkpoints read it as BC-OH's.

**The past actions** are the expert's labels of the `k` rows before each sample in its episode
(`history_index(..., k, offset=1)`); before an episode's first step they repeat its first action, as the
observation history repeats its first frame and `_batch` the previous action (so at `t = 0` the target is `a_0`).

Knobs (`PtpKnobs`): `past` = k (static: the head's width), default 1: the authors predict the past actions over
their whole observation context, and the project's default history (2 frames, `o_{t−1}, o_t`) holds one past step,
so k = H − 1 is theirs (`--set ptp.past=3` under PALR's history 4); `weights` (a grid axis, traced: every weight and
seed in one `jit(vmap(scan))`), default 1: the past actions together weigh as the current one. The authors' one
sequence weighs every token alike, which is `weight = k` here (equal at k = 1).

Where ours differs: their policy is a diffusion (or regression) transformer whose one head emits past, current
and future tokens, and they find PTP's benefit mostly in that head; ours predicts `a_t` alone (no future chunk)
with the project's MLP head, and the past from a head of its own (`P`: one hidden layer of 300 with
LeakyReLU(0.2), the policy head's shape), so the shared part is everything up to the embedding. Not ours: their
multistage training (a short-context encoder, then the head on cached long-context embeddings) and their
test-time self-verification (sampling candidates and keeping the one whose predicted past matches the executed
actions): evaluation reads the plain policy.

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (the policy's objective), `"unweighted_loss"` (the
BC loss) and `"past_loss"` (the past term before its weight).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from ape_jax import methods
from ape_jax.baselines._batch import errors, sample_batch
from ape_jax.history import history_index
from ape_jax.knobs import nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, adam_step, learning_rate, make_train, policy_apply,
                             scanned_learner, trainable)

NAME = "ptp"
DEFAULT_PAST = 1        # k = H − 1 at the project's default history 2 (the authors: the whole context)
DEFAULT_WEIGHT = 1.0    # the past actions together weigh as the current one (the authors: each token alike)
PAST_HIDDEN = 300       # P's hidden layer: the policy head's width (models.Head)


@dataclasses.dataclass(frozen=True)
class PtpKnobs:
    """PTP's own settings (`--set ptp.KNOB=VALUE`; the module docstring).

    Attributes:
      past: k, the previous actions the auxiliary head predicts (static: changing it recompiles).
      weights: a grid axis: the past term's weight in the policy's loss, each >= 0 (0: BC-OH).
    """

    past: int = DEFAULT_PAST
    weights: tuple[float, ...] = (DEFAULT_WEIGHT,)

    def __post_init__(self):
        if isinstance(self.past, bool) or not isinstance(self.past, int) or self.past < 1:
            raise ValueError(f"{NAME}.past must be an integer >= 1, got {self.past!r}")
        if not self.weights or len(set(self.weights)) != len(self.weights):
            raise ValueError(f"{NAME}.weights must list each weight once, at least one, got {self.weights!r}")
        for w in self.weights:
            nonnegative(f"{NAME}.weights", w)


@struct.dataclass
class PtpHparams:
    """Traced knobs of one PTP run (stack them along a leading axis for seeds × weights)."""

    weight: jax.Array   # [] float32, the past term's weight; 0 = BC-OH
    lr: jax.Array       # [] float32, the policy's and the head's

    @classmethod
    def make(cls, weight: float = DEFAULT_WEIGHT, lr: float = 2e-4) -> PtpHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        nonnegative(f"{NAME} weight", weight)
        positive("learning rate", lr)
        return cls(weight=jnp.float32(weight), lr=jnp.float32(lr))


class PastHead(nn.Module):
    """`P`: `[B, E]` embeddings -> `[B, past, A]` predicted previous actions `a_{t−past..t−1}`, oldest first."""

    action_dim: int
    past: int
    hidden: int = PAST_HIDDEN

    @nn.compact
    def __call__(self, embedding: jax.Array) -> jax.Array:
        h = nn.leaky_relu(nn.Dense(self.hidden, name="hidden")(embedding), negative_slope=0.2)
        out = nn.Dense(self.past * self.action_dim, name="past")(h)
        return out.reshape(out.shape[:-1] + (self.past, self.action_dim))


@struct.dataclass
class PtpState:
    """The scan carry: the policy's variables and moments (as BC-OH's), and the past head's."""

    params: Any          # cfg.model() variables
    opt_state: Any       # on trainable(params)
    head: Any            # PastHead variables
    head_opt: Any
    step: jax.Array      # [] int32
    key: jax.Array


def past_actions(data: Data, idx: jax.Array, past: int) -> jax.Array:
    """`[B, past, A]`: the expert's actions at the `past` rows before each row of `idx` (indices into
    `data.action`), oldest first; before its episode's first step each repeats that first action."""
    return data.action[history_index(data.t, idx, past, offset=1)]


def make_ptp(cfg: LearnerConfig, past: int = DEFAULT_PAST) -> Learner:
    """The pure functions of PTP for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe (`cfg.model()` the policy, state or image; its embedding `φ`).
      past: k, the previous actions the head predicts (>= 1).

    Returns:
      A `Learner` whose policy parameters are `cfg.model()`'s; `init(key)` draws the policy and run key as
      `make_train(cfg).init(jax.random.split(key)[0])` does and the head from the other half: at weight 0 its
      policy trains as BC-OH's from that key, on the same batches.
    """
    PtpKnobs(past=past)   # the one rule for `past`
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()
    head = PastHead(cfg.action_dim, past)
    dummy = base.policy_input(jnp.zeros((1, cfg.history, *cfg.obs_shape), jnp.float32))
    embed = jax.eval_shape(lambda: model.apply(model.init(jax.random.PRNGKey(0), dummy), dummy,
                                               return_embedding=True)[1]).shape[-1]

    def init(key: jax.Array, hp: PtpHparams, data: Data) -> PtpState:
        key_policy, key_head = jax.random.split(key)
        key_init, key_run = jax.random.split(key_policy)  # make_train's init of key_policy
        params = base.init_policy(key_init, data)
        head_params = head.init(key_head, jnp.zeros((1, embed), jnp.float32))
        return PtpState(params=params, opt_state=adam.init(trainable(params)), head=head_params,
                        head_opt=adam.init(head_params), step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: PtpState, hp: PtpHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        batch = sample_batch(cfg, base, data, key_step)
        _, idx = data.sample(key_step, cfg.batch_size)   # the batch's rows (the same draw as `sample_batch`'s)
        target = past_actions(data, idx, past)
        lr = learning_rate(cfg, hp.lr, state.step)

        def objective(params, head_params):
            """The policy's gradient is BC's plus `weight` × the past term's; the head's the past term's whole."""
            (predicted, embedding), variables = policy_apply(model, {**state.params, **params}, batch.x, train=True,
                                                             return_embedding=True)
            bc = jnp.mean(errors(cfg, predicted, batch.action))
            held = jax.lax.stop_gradient(embedding)
            seen = held + hp.weight * (embedding - held)
            past_loss = jnp.mean(errors(cfg, head.apply(head_params, seen), target))
            return bc + past_loss, (bc, past_loss, variables)

        (_, (bc, past_loss, after)), (grads, head_grads) = jax.value_and_grad(objective, (0, 1), has_aux=True)(
            trainable(state.params), state.head)
        params, opt_state = adam_step(adam, trainable(state.params), grads, state.opt_state, lr)
        head_params, head_opt = adam_step(adam, state.head, head_grads, state.head_opt, lr)
        state = state.replace(params={**after, **params}, opt_state=opt_state, head=head_params, head_opt=head_opt,
                              step=state.step + 1)
        return state, {"loss": bc + hp.weight * past_loss, "unweighted_loss": bc, "past_loss": past_loss}

    return scanned_learner(cfg, base, init, update)


methods.register(methods.Method(
    NAME, "PTP", grid=lambda ctx: [{"weight": w} for w in ctx.knobs_of(NAME).weights],
    hparams=lambda settings, lr, row: PtpHparams.make(settings["weight"], lr=lr),
    program=NAME, learner=lambda ctx: make_ptp(ctx.cfg, ctx.knobs_of(NAME).past), knobs=PtpKnobs,
    module=__name__))
