"""DAgger (Ross, Gordon & Bagnell, 2011): roll out the learner, have the expert label what it visits, retrain.

The only method of the benchmark that queries the expert beyond the
demonstrations; every other method learns from the fixed dataset alone.

    learner = make_dagger(cfg, env, expert, obs_mean, obs_std, budget=len(train))
    params, metrics = jax.jit(learner.train)(key, Hparams.make(lr=1e-3), data)
    params, metrics = jax.jit(jax.vmap(learner.train, (0, 0, None)))(keys, hps, data)   # seeds

Our reading of the algorithm (the paper of the benchmark gives no details):

- **Rounds.** `rounds = R` rounds (default 4) of `cfg.iterations // R`
  iterations each, so DAgger takes as many gradient steps as one BC run (up
  to the remainder of the division). Round 0 trains on the demonstrations
  only (= BC with the configured history `H`). Before each round
  `r = 1 .. R−1` the current policy is rolled out and the expert labels the
  visited states; the labelled rows are added to the aggregated dataset and
  training continues on all of it.
- **Warm start.** Training continues across rounds: the policy's variables
  (with BatchNorm's running statistics), Adam moments, the step counter and
  with it the learning-rate schedule (×0.1 at each of `cfg.lr_boundaries`, as
  in `make_train`) carry over. The
  original algorithm retrains from scratch each round; warm starting spends
  the same number of gradient steps in total and does not discard what the
  earlier rounds learnt.
- **Query budget.** `budget` expert labels in all (the sweep's default: the
  number of demonstration transitions, so the aggregated dataset ends at twice
  the demonstrations): `budget // (R−1)` per round, the last round taking the
  remainder, so exactly `budget` rows are added. With `budget = 0` no row is
  added and DAgger is BC-OH trained in R warm-started chunks.
- **β-mixing.** The rollout of round `r` executes the mixture policy
  `π_r = β_r·π* + (1−β_r)·π̂`: at each step, independently, the expert's
  action with probability `β_r`, else the learner's. `β_r = beta^r` with
  `beta = 0.5` by default, i.e. 0.5, 0.25, 0.125 for rounds 1, 2, 3 (the
  paper's "β_i = p^(i−1)" schedule, with round 0 being pure expert data:
  β_0 = 1). The label is always the expert's clean action, whoever acted.
- **Labels.** The expert sees the full state (`env.expert_observation`) and
  acts deterministically; its label is what the sweep gives as `expert`: the
  demonstrations' own expert (a `--dataset`'s, `collect.dataset_expert`), its
  output clipped to the action bounds or raw as `protocol.labels` says
  (`collect.labeller`), like the demonstrations' labels. Where the expert
  acts, its action is executed clipped to `env.action_bounds`. The learner's
  own policy acts exactly as at evaluation (`evaluate.history_policy`): its
  last `H` standardised observations, padded at the episode start by
  repeating the first one, its actions clipped to `env.action_bounds`. A sweep
  from a dataset whose expert cannot be queried refuses DAgger
  (`sweep.prepare`).
- **Rollouts.** `num_envs` (default 16) environment streams run in parallel
  (`vmap`), `lax.scan` over `⌈q / num_envs⌉` steps for `q` queries. A stream resets (a fresh
  key, the policy's history restarted) after a terminal state or after
  `env.episode_length` steps, like the demonstrations' episodes; a terminal
  state is never recorded. Each step records the observation before acting,
  standardised like the demonstrations (`(obs − mean) / std`; images raw
  uint8), its time `t` within the episode and the expert's label. Streams are
  appended one after another (episodes contiguous, `t` restarting at 0), so
  histories are built by `ape_jax.history.history_index` exactly as on the
  demonstrations; the records are cut to exactly `q` rows (the last streams
  lose their tails). Every round rolls out the same number of steps (enough
  for the largest round), so one compiled rollout serves all rounds.
- **Training.** Minibatches of `cfg.batch_size` rows are drawn uniformly with
  replacement from the aggregated dataset's sampling table (the split's rows,
  `Data.rows` or every row, and the expert-labelled rollouts' rows alike, no
  weighting); histories read whole episodes, the demonstrations' and the
  rollouts' (which have their own `t`). The loss is `make_train`'s (L2 or L1,
  mean over the batch), the step the recipe's (`cfg.optimizer()`, the policy
  applied in training mode: BatchNorm on batch statistics). Of `Hparams` only
  `lr` is used (the weighting and history dropout are ignored), so the grid's
  `Hparams` vmap as usual.
- **Randomness.** `init` splits its key into the network's initialisation
  key, the minibatch key (`fold_in(key, step)` per step) and the rollout key
  (`fold_in(key, r)` for round r's rollout), so runs are reproducible and
  seeds independent.

Each seed carries its own aggregated dataset in its state (`Buffer`): the
demonstrations' `M` rows of whole episodes followed by room for `budget`
rollout rows, allocated at `init`, and a sampling table of `N + budget` row
indices (the split's `N` rows, then the appended rows') of which the first
`count` are valid, so `vmap` over seeds (or learning rates) keeps every run's
data apart (for images that is `(M + budget) × H × W × 3` bytes per run). Everything is jit-able; all
rounds run in one compiled `train`, or round by round with `next_round`
(`init`, `run`, `next_round`, `run`, ...), which computes the same.
"""

from __future__ import annotations

from typing import Any
from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

import envs
from ape_jax.evaluate import history_policy
from ape_jax.history import history_index
from ape_jax.learner import (Data, Hparams, Learner, LearnerConfig, action_errors, augment, gradient_step,
                             learning_rate, make_train, policy_apply, train_in_rounds, trainable)
from ape_jax import methods

ROUNDS = 4
NUM_ENVS = 16
BETA = 0.5


@struct.dataclass
class Labelled:
    """Expert-labelled rollout records; every field has leading dim `[num_envs * num_steps]`, stream-major.

    Attributes:
      obs: what the learner saw, `[M, *obs_shape]`: standardised float32 (states) or uint8 (images).
      action: the expert's clean action, the label, `[M, A] float32`.
      t: time within the episode, `[M] int32`, 0 at every reset.
      expert_obs: what the expert saw, `[M, d] float32` (`env.expert_observation`).
      expert_acted: whether the expert's action was executed, `[M] bool`.
    """

    obs: jax.Array
    action: jax.Array
    t: jax.Array
    expert_obs: jax.Array
    expert_acted: jax.Array


@struct.dataclass
class Buffer:
    """The aggregated dataset of one run: rows of whole episodes, and the table of the rows minibatches draw.

    `obs`, `action` and `t` hold the demonstrations' `M` rows (whole episodes), then room for `budget` rollout
    rows; `rows` holds the split's `N` row indices (`Data.rows`, or `0 .. M − 1`), then the appended rows'.
    """

    obs: jax.Array     # [M + budget, *obs_shape], the dtype of the demonstrations' obs
    action: jax.Array  # [M + budget, A] float32
    t: jax.Array       # [M + budget] int32
    rows: jax.Array    # [N + budget] int32, indices into obs/action/t; the first `count` valid
    count: jax.Array   # [] int32, N + the rows appended so far

    @property
    def end(self) -> jax.Array:
        """`[] int32`: rows of `obs` in use, where the next rollout is appended (`M` + those appended)."""
        return self.count + (self.t.shape[0] - self.rows.shape[0])

    def sample(self, key: jax.Array, batch: int) -> jax.Array:
        """`[batch] int32` rows (indices into `obs`), uniformly with replacement from the valid table entries."""
        return self.rows[jax.random.randint(key, (batch,), 0, self.count)]


@struct.dataclass
class DaggerState:
    params: Any
    opt_state: Any
    step: jax.Array         # [] int32, gradient steps so far (all rounds)
    key: jax.Array          # minibatch key: fold_in(key, step)
    rollout_key: jax.Array  # rollout key: fold_in(rollout_key, round)
    round: jax.Array        # [] int32, the round being trained
    buffer: Buffer


def round_sizes(budget: int, rounds: int) -> tuple[int, ...]:
    """Expert queries before each round: `(0, q, ..., q, q + remainder)`, `rounds` entries summing to `budget`."""
    if budget < 0 or rounds < 2:
        raise ValueError(f"DAgger needs budget >= 0 and rounds >= 2, got budget={budget}, rounds={rounds}")
    each = budget // (rounds - 1)
    return (0,) + (each,) * (rounds - 2) + (budget - each * (rounds - 2),)


def label_rollout(cfg: LearnerConfig, env: envs.Env, expert: Callable[[jax.Array], jax.Array],
                  obs_mean: jax.Array | None, obs_std: jax.Array | None, params: Any, key: jax.Array,
                  beta: jax.Array | float, num_envs: int, num_steps: int) -> Labelled:
    """Rolls out the β-mixture of expert and learner and labels every visited state with the expert.

    Traceable (call it under `jit`); see the module docstring for resets and records.

    Args:
      cfg: the learner's static settings (history length, model).
      env: the environment, in the learner's observation mode.
      expert: `full_obs [d] -> action [A]`, deterministic.
      obs_mean, obs_std: the demonstrations' standardisation, `[D]` each, or `None` (images).
      params: the learner's policy parameters (for `cfg.model()`).
      key: PRNG key of this rollout.
      beta: `[]` probability of executing the expert's action at each step.
      num_envs: parallel environment streams.
      num_steps: steps per stream.

    Returns:
      `Labelled`, leading dim `num_envs * num_steps`, stream after stream.
    """
    policy = history_policy(cfg, obs_mean, obs_std, env)
    beta = jnp.asarray(beta, jnp.float32)

    def stream(key_stream):
        key_reset, key_steps = jax.random.split(key_stream)
        state = env.reset(key_reset)

        def step(loop, i):
            state, history, t = loop
            key_mix, key_act, key_next = jax.random.split(jax.random.fold_in(key_steps, i), 3)
            full = env.expert_observation(state)
            label = jnp.asarray(expert(full), jnp.float32)
            own, history = policy.act(params, history, state, key_act)
            expert_acts = jax.random.uniform(key_mix) < beta
            # the history's newest entry is this state's observation, standardised as in training
            record = Labelled(obs=history[-1], action=label, t=t, expert_obs=full, expert_acted=expert_acts)
            # the expert's action as it executes: clipped (an unbounded label, `protocol.labels="raw"`, is not)
            executed = jnp.clip(label, *env.action_bounds)
            nxt = env.step(state, jnp.where(expert_acts, executed, own))
            ended = (nxt.done > 0) | (t + 1 >= env.episode_length)
            # auto-reset by selection: under vmap a `cond` would compute both branches anyway
            fresh = env.reset(key_next)
            nxt = jax.tree.map(lambda a, b: jnp.where(ended, a, b), fresh, nxt)
            history = jnp.where(ended, policy.init(params, fresh), history)
            return (nxt, history, jnp.where(ended, 0, t + 1)), record

        loop = (state, policy.init(params, state), jnp.zeros((), jnp.int32))
        return jax.lax.scan(step, loop, jnp.arange(num_steps))[1]

    records = jax.vmap(stream)(jax.random.split(key, num_envs))
    return jax.tree.map(lambda x: x.reshape((num_envs * num_steps,) + x.shape[2:]), records)


def make_dagger(cfg: LearnerConfig, env: envs.Env, expert: Callable[[jax.Array], jax.Array],
                obs_mean: jax.Array | None, obs_std: jax.Array | None, budget: int, rounds: int = ROUNDS,
                num_envs: int = NUM_ENVS, beta: float = BETA) -> Learner:
    """DAgger as a round-based `Learner` (module docstring); `hp` is an `Hparams`, of which only `lr` is used.

    Args:
      cfg: the learner's static settings; `cfg.iterations // rounds` iterations per round.
      env: the environment, in the observation mode of the demonstrations.
      expert: `full_obs [d] -> label [A]`, jit-able (`ape_jax.pipeline.sweep.Prepared.expert`); executed clipped.
      obs_mean, obs_std: the demonstrations' standardisation, `[D]` each; `None` for images.
      budget: expert queries in all, >= 0 (rows added to the demonstrations).
      rounds: R >= 2, round 0 on the demonstrations alone.
      num_envs: parallel environment streams of each rollout.
      beta: β_r = beta^r for round r, in [0, 1].

    Returns:
      A `Learner` whose `train(key, hp, data)` runs every round; `data` is the
      demonstrations' training split (obs standardised as `obs_mean/obs_std` say).
    """
    sizes = round_sizes(budget, rounds)
    if num_envs < 1:
        raise ValueError(f"DAgger needs num_envs >= 1, got {num_envs}")
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"DAgger's beta must be in [0, 1], got {beta}")
    if cfg.iterations < rounds:
        raise ValueError(f"DAgger needs iterations >= rounds, got {cfg.iterations} iterations for {rounds} rounds")
    if tuple(env.observation_shape) != tuple(cfg.obs_shape) or env.action_size != cfg.action_dim:
        raise ValueError(f"env {env.name!r} observes {env.observation_shape} and acts in {env.action_size} dims, "
                         f"the learner expects {cfg.obs_shape} and {cfg.action_dim}")
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()
    widest = max(sizes)                        # one rollout shape serves every round
    steps = -(-widest // num_envs)

    def init(key: jax.Array, hp: Hparams, data: Data) -> DaggerState:
        if tuple(data.obs.shape[1:]) != tuple(cfg.obs_shape):
            raise ValueError(f"data.obs has rows of shape {data.obs.shape[1:]}, the learner expects {cfg.obs_shape}")
        key_init, key_train, key_rollout = jax.random.split(key, 3)
        params = base.init_policy(key_init, data)
        split = jnp.arange(data.obs.shape[0], dtype=jnp.int32) if data.rows is None else data.rows
        pad = lambda x: jnp.concatenate([x, jnp.zeros((budget,) + x.shape[1:], x.dtype)])  # noqa: E731
        buffer = Buffer(obs=pad(data.obs), action=pad(jnp.asarray(data.action, jnp.float32)),
                        t=pad(jnp.asarray(data.t, jnp.int32)), rows=pad(jnp.asarray(split, jnp.int32)),
                        count=jnp.asarray(data.size, jnp.int32))
        return DaggerState(params=params, opt_state=adam.init(trainable(params)), step=jnp.zeros((), jnp.int32),
                           key=key_train, rollout_key=key_rollout, round=jnp.zeros((), jnp.int32), buffer=buffer)

    def update(state: DaggerState, hp: Hparams):
        buf = state.buffer
        key_step = jax.random.fold_in(state.key, state.step)
        idx = buf.sample(key_step, cfg.batch_size)
        x = base.policy_input(augment(cfg, jax.random.fold_in(key_step, 2),
                                      buf.obs[history_index(buf.t, idx, cfg.history)]))

        def loss_fn(variables):
            predicted, variables = policy_apply(model, variables, x, train=True)
            loss = jnp.mean(action_errors(cfg, predicted, buf.action[idx]))
            return loss, (loss, variables)

        params, opt_state, loss, _ = gradient_step(adam, state.params, state.opt_state,
                                                   learning_rate(cfg, hp.lr, state.step), loss_fn)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": loss}

    def run(state: DaggerState, hp: Hparams, data: Data, n: int):
        return jax.lax.scan(lambda s, _: update(s, hp), state, None, length=n, unroll=cfg.unroll)

    def next_round(state: DaggerState, hp: Hparams, data: Data) -> DaggerState:
        r = state.round + 1
        if widest == 0:
            return state.replace(round=r)
        queries = jnp.asarray(sizes + (0,), jnp.int32)[jnp.minimum(r, rounds)]  # no rows past the last round
        records = label_rollout(cfg, env, expert, obs_mean, obs_std, state.params,
                                jax.random.fold_in(state.rollout_key, r), jnp.float32(beta) ** r, num_envs, steps)
        buf = state.buffer
        offset = jnp.arange(widest)
        added = offset < queries
        at = jnp.where(added, buf.end + offset, buf.t.shape[0])  # out of range: dropped
        put = lambda dst, src: dst.at[at].set(src[:widest].astype(dst.dtype), mode="drop")  # noqa: E731
        entries = jnp.where(added, buf.count + offset, buf.rows.shape[0])
        buf = Buffer(obs=put(buf.obs, records.obs), action=put(buf.action, records.action),
                     t=put(buf.t, records.t), rows=buf.rows.at[entries].set(buf.end + offset, mode="drop"),
                     count=buf.count + queries)
        return state.replace(round=r, buffer=buf)

    learner = Learner(init=init, run=run, train=None, policy_input=base.policy_input,
                      per_sample_loss=base.per_sample_loss, policy_params=lambda s: s.params,
                      rounds=rounds, round_iterations=cfg.iterations // rounds, next_round=next_round)
    return learner._replace(train=lambda key, hp, data: train_in_rounds(learner, key, hp, data))


def _learner(ctx) -> Learner:
    if ctx.expert is None:
        raise ValueError("dagger queries the expert, and these demonstrations have none that can be queried")
    return make_dagger(ctx.cfg, ctx.env, ctx.expert, ctx.obs_mean, ctx.obs_std, budget=ctx.n_train)


methods.register(methods.Method(
    "dagger", "DAgger", grid=lambda ctx: [{"rounds": ROUNDS, "budget": ctx.n_train}],
    hparams=lambda settings, lr, row: Hparams.make("uniform", lr=lr), program="dagger", learner=_learner,
    online=True, module=__name__))
