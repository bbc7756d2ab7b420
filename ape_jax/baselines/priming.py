"""Priming: PrimeNet (Wen, Qian, Lin, Teng, Jayaraman and Gao, ICML 2022, "Fighting Fire with Fire: Avoiding DNN
Shortcuts through Priming", Sec. 3, the priming architecture, and Sec. 4, its imitation experiments) on the project's
network, as a pure-functional `Learner` and a composite policy.

A *key input* network gives a rough estimate of the output from the input the task's knowledge says matters (for
copycat behavioural cloning: the current observation), and the main network reads that estimate, the *prime*, beside
its usual input, so the easy shortcut (the previous action in the history) is no longer the simplest one. Here the
key-input network is BC-SO (the recipe's `StatePolicy` on the current observation, `o_t`) and the main network a
history policy (BC-OH's `StatePolicy` on `o_{t−H+1..t}`) that also reads `w · sg(p̂_t)`:

    p̂_t = π_prime(o_t),     â_t = π(o_{t−H+1..t}, w · sg(p̂_t)),     L = mean_i ℓ(â_t, a_t) + mean_i ℓ(p̂_t, a_t),

`sg` a stop-gradient (the prime is data to the history policy, as in PrimeNet, where the key-input network is
trained first and kept fixed), `ℓ` the project's loss. The prime enters the history policy's first layer as a
second input block: that layer computes `K_x o + K_p (w · p̂)` (`StatePolicy`'s `first_layer_input`), which is a
layer on the concatenation `[o, w · p̂]` with its kernel split in two.

Knobs (`PrimingKnobs`, `--set priming.KNOB=VALUE`): `source`, where the prime comes from: `"bc-so"` (the default,
PrimeNet's staging: the key-input network trained first and kept fixed), the sweep's own BC-SO policy of the run's
seed, trained before this program and read without its gradient (`Method.reads`: the sweep refuses priming without
`bc-so` among its methods); or `"joint"`, BC-SO trained in the same program beside the history policy, on the same
minibatches (two networks learn: about twice BC-OH's time per update, where `"bc-so"` adds one forward pass);
`weights`, a grid axis scaling the prime, default `(1.0,)` (PrimeNet feeds the prime as it is). **Neutral:** weight 0
gives the history policy a zero block, so it trains exactly as BC-OH (the same initialisation from the same key,
minibatches, loss and gradients; tested for both sources), its prime block idle.

The composite is the trained policy (`PrimedPolicy`): at evaluation the prime network reads the current frame and the
history policy the history and the prime, both with BatchNorm's running statistics where the recipe has them. Its
variables hold the prime's projection already scaled by its run's weight (`policy_params`), so it acts without the
weight; `policy_runtime` (`ape_jax.evaluate.Runtime`) is how evaluation, the loss analysis, the videos and the
copycat probes read it; the probes read the history policy's embedding.

Our readings:

- **The stages are the sweep's programs.** PrimeNet trains the key-input network first and the main network after
  it; `"bc-so"` reads the sweep's BC-SO, trained first as a program of its own (the same network, initialisation,
  loss and budget as BC-SO's row of the table), so the prime is exactly the table's BC-SO policy. `"joint"` trains
  both in every iteration of one scan instead, the history policy reading the prime as it currently is.
- **The prime network is BC-SO's** (the recipe's network, init and loss). Under `"joint"` it trains on the history
  policy's minibatch rows rather than its own draws, its initialisation from the run key's second half (the history
  policy's and its minibatches from the first, as `make_train`'s from that key); under `"bc-so"` it is read with
  BatchNorm's running statistics, as BC-SO acts.
- **The projection `K_p`** is initialised as the recipe initialises a Dense layer over its own fan-in (`A`), where a
  layer on the concatenation would draw its rows over the fan-in `H · D + A`.
- **State observations only**: the key input is the current observation's slice of the stacked states; images are
  refused (`refusal`), and so is a history of 1 (nothing to prime against).
- **Cost**: `"bc-so"` adds the prime's forward pass to BC-OH's update; `"joint"` trains two networks per iteration,
  about twice BC-OH's work (`experiments.bench_train --methods-only`, docs/speed.md).

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` (`L`; under `"bc-so"` the history policy's alone),
`"unweighted_loss"` (the history policy's BC loss, BC-OH's) and `"prime_loss"` (the prime network's, BC-SO's).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from ape_jax import methods
from ape_jax.evaluate import Runtime
from ape_jax.history import history_index
from ape_jax.knobs import nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, action_errors, gradient_step, learning_rate, make_train,
                             policy_apply, scanned_learner, trainable)
from ape_jax.models import INITS, StatePolicy

NAME = "priming"
SOURCES = ("bc-so", "joint")  # where the prime comes from (the module docstring)
DEFAULT_SOURCE = "bc-so"      # PrimeNet: the key-input network is trained first and kept fixed (its Sec. 3)
READS = "bc-so"               # the method whose trained policies the "bc-so" source reads
DEFAULT_WEIGHT = 1.0      # PrimeNet feeds the prime to the main network as it is


@dataclasses.dataclass(frozen=True)
class PrimingKnobs:
    """Priming's own settings (`--set priming.KNOB=VALUE`; the module docstring).

    Attributes:
      source: where the prime comes from, one of `SOURCES`: `"bc-so"`, the sweep's BC-SO (its run of the same
        seed); `"joint"`, BC-SO trained beside the history policy.
      weights: a grid axis: the prime's scale in the history policy's input, each >= 0 (0: BC-OH).
    """

    source: str = DEFAULT_SOURCE
    weights: tuple[float, ...] = (DEFAULT_WEIGHT,)

    def __post_init__(self):
        if self.source not in SOURCES:
            raise ValueError(f"{NAME}.source must be one of {', '.join(SOURCES)}, got {self.source!r}")
        if not self.weights or len(set(self.weights)) != len(self.weights):
            raise ValueError(f"{NAME}.weights must list each weight once, at least one, got {self.weights!r}")
        for w in self.weights:
            nonnegative(f"{NAME}.weights", w)


@struct.dataclass
class PrimingHparams:
    """Traced knobs of one Priming run (stack them along a leading axis for seeds × weights)."""

    weight: jax.Array   # [] float32, the prime's scale; 0 = BC-OH
    lr: jax.Array       # [] float32, both networks'
    prime: Any = None   # source "bc-so": the BC-SO policy's variables the prime is read from (`read`)

    @classmethod
    def make(cls, weight: float = DEFAULT_WEIGHT, lr: float = 2e-4) -> PrimingHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        nonnegative(f"{NAME} weight", weight)
        positive("learning rate", lr)
        return cls(weight=jnp.float32(weight), lr=jnp.float32(lr))

    def read(self, params: Any) -> PrimingHparams:
        """These hyperparameters with the prime's variables (`Method.reads`: BC-SO's trained policies, each run's
        own seed's, stacked as the runs are)."""
        return self.replace(prime=params)


class PrimedPolicy(nn.Module):
    """`[..., H * D]` stacked states -> `[..., A]`: the prime network (`prime`, a `StatePolicy` on the last `D`
    entries, the current observation) and the history policy (`policy`, a `StatePolicy` on all of them) reading the
    prime through `prime_input` (`[A, 300]`, no bias) added to its first layer.

    `__call__` is the trained policy (`return_embedding`: the history policy's embedding; `train` as `StatePolicy`'s);
    `primed` also returns the prime, and scales it by `prime_weight` (training's traced weight; the trained
    variables hold the projection already scaled, so the policy acts at weight 1).
    """

    action_dim: int
    obs_dim: int
    batchnorm: bool = False
    weights_init: str = "lecun"
    bn_momentum: float = 0.1
    dtype: str = "float32"

    def setup(self):
        kw = dict(batchnorm=self.batchnorm, weights_init=self.weights_init, bn_momentum=self.bn_momentum,
                  dtype=self.dtype)
        self.prime = StatePolicy(self.action_dim, **kw)
        self.policy = StatePolicy(self.action_dim, **kw)
        self.prime_input = nn.Dense(StatePolicy.hidden[0], use_bias=False, kernel_init=INITS[self.weights_init],
                                    dtype=self.dtype)

    def __call__(self, x: jax.Array, return_embedding: bool = False, train: bool = False
                 ) -> jax.Array | tuple[jax.Array, jax.Array]:
        return self.primed(x, return_embedding=return_embedding, train=train)[0]

    def primed(self, x: jax.Array, prime_weight: jax.Array | float = 1.0, return_embedding: bool = False,
               train: bool = False) -> tuple[Any, jax.Array]:
        """`(the history policy's output, the prime [..., A])`."""
        prime = self.prime(x[..., -self.obs_dim:], train=train)
        return self.reading(x, prime, prime_weight, return_embedding, train), prime

    def prime_of(self, x: jax.Array) -> jax.Array:
        """The prime `[..., A]` as the prime network acts (BatchNorm's running statistics)."""
        return self.prime(x[..., -self.obs_dim:], train=False)

    def reading(self, x: jax.Array, prime: jax.Array, prime_weight: jax.Array | float = 1.0,
                return_embedding: bool = False, train: bool = False) -> Any:
        """The history policy's output on `x` and a given `prime` (without its gradient)."""
        block = self.prime_input(prime_weight * jax.lax.stop_gradient(prime))
        return self.policy(x, return_embedding, train, first_layer_input=block)


def primed_model(cfg: LearnerConfig) -> PrimedPolicy:
    """The composite of `cfg`'s recipe (its `StatePolicy` settings) on `cfg.obs_shape` states."""
    return PrimedPolicy(cfg.action_dim, obs_dim=cfg.obs_shape[0], batchnorm=cfg.network == "bn-mlp",
                        weights_init=cfg.init, bn_momentum=cfg.bn_momentum, dtype=cfg.dtype)


@struct.dataclass
class PrimingState:
    """The scan carry: the composite's variables, one Adam's moments over both networks (elementwise, so two
    optimisers), the step, the key and the run's weight."""

    params: Any              # PrimedPolicy variables, `prime_input` unscaled
    opt_state: Any           # on trainable(params)
    step: jax.Array          # [] int32
    key: jax.Array
    weight: jax.Array        # [] float32


def policy_params(state: PrimingState) -> Any:
    """The trained composite's variables: the prime's projection scaled by the run's weight, so `PrimedPolicy`
    acts at weight 1 (the module docstring). `state` may be one run's or the grid's, stacked over runs (the weight
    `[R]`, the kernel `[R, A, F]`): the weight scales each run's own kernel."""
    params = state.params["params"]
    kernel, weight = params["prime_input"]["kernel"], state.weight
    scaled = {"kernel": kernel * weight.reshape(weight.shape + (1,) * (kernel.ndim - weight.ndim))}
    return {**state.params, "params": {**params, "prime_input": scaled}}


def make_priming(cfg: LearnerConfig, source: str = DEFAULT_SOURCE) -> Learner:
    """The pure functions of Priming for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe; state observations and `cfg.history` >= 2.
      source: where the prime comes from (`SOURCES`).

    Returns:
      A `Learner` whose policy parameters are a `PrimedPolicy`'s (`policy_params`); its `init(key)` draws the
      history policy and its minibatches as `make_train(cfg).init(jax.random.split(key)[0])` does, the
      projection (and under `"joint"` the prime network) from the other half; under `"bc-so"` the prime network
      is the hyperparameters' `prime` (`PrimingHparams.read`).
    """
    PrimingKnobs(source=source)   # the one rule for the source
    if cfg.images:
        raise ValueError(f"{NAME} runs on state observations (its key input is the current state's slice), got "
                         f"obs_shape {cfg.obs_shape}")
    if cfg.history < 2:
        raise ValueError(f"{NAME} primes a history policy: it needs a history of at least 2, got {cfg.history}")
    base = make_train(cfg)
    prime_base = make_train(dataclasses.replace(cfg, history=1))
    model, adam = primed_model(cfg), cfg.optimizer()

    def init(key: jax.Array, hp: PrimingHparams, data: Data) -> PrimingState:
        key_policy, key_prime = jax.random.split(key)
        key_init, key_run = jax.random.split(key_policy)   # make_train's init of key_policy
        key_net, key_block = jax.random.split(key_prime)
        policy = base.init_policy(key_init, data)
        if source == "joint":
            prime = prime_base.init_policy(key_net, data)
        elif hp.prime is None:
            raise ValueError(f"{NAME}.source {source!r} reads BC-SO's trained policies, and none were given "
                             "(PrimingHparams.read)")
        else:
            prime = hp.prime
        block = nn.Dense(StatePolicy.hidden[0], use_bias=False, kernel_init=INITS[cfg.init]).init(
            key_block, jnp.zeros((1, cfg.action_dim), jnp.float32))["params"]
        variables = {"params": {"policy": policy["params"], "prime": prime["params"], "prime_input": block}}
        if "batch_stats" in policy:
            variables["batch_stats"] = {"policy": policy["batch_stats"], "prime": prime["batch_stats"]}
        return PrimingState(params=variables, opt_state=adam.init(trainable(variables)),
                            step=jnp.zeros((), jnp.int32), key=key_run, weight=hp.weight)

    def update(state: PrimingState, hp: PrimingHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        _, idx = data.sample(key_step, cfg.batch_size)   # make_train's rows
        x = base.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
        action = data.action[idx]

        def loss_fn(variables):
            if source == "joint":
                (predicted, prime), variables = policy_apply(model, variables, x, train=True,
                                                             method=PrimedPolicy.primed, prime_weight=hp.weight)
                bc, prime_bc = (jnp.mean(action_errors(cfg, p, action)) for p in (predicted, prime))
                return bc + prime_bc, ((bc, prime_bc), variables)
            # the prime as BC-SO acts, read without its gradient: its variables get none, so Adam leaves them
            prime = jax.lax.stop_gradient(model.apply(variables, x, method=PrimedPolicy.prime_of))
            predicted, variables = policy_apply(model, variables, x, train=True, method=PrimedPolicy.reading,
                                                prime=prime, prime_weight=hp.weight)
            bc, prime_bc = (jnp.mean(action_errors(cfg, p, action)) for p in (predicted, prime))
            return bc, ((bc, prime_bc), variables)

        params, opt_state, loss, (bc, prime_bc) = gradient_step(
            adam, state.params, state.opt_state, learning_rate(cfg, hp.lr, state.step), loss_fn)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": bc, "prime_loss": prime_bc}

    learner = scanned_learner(cfg, base, init, update, policy_params=policy_params)

    def per_sample_loss(params, data: Data, idx: jax.Array) -> jax.Array:
        x = base.policy_input(data.obs[history_index(data.t, idx, cfg.history)])
        return action_errors(cfg, model.apply(params, x), data.action[idx])

    return learner._replace(per_sample_loss=per_sample_loss)


def policy_runtime(cfg: LearnerConfig, settings: Sequence[Mapping[str, float]]) -> Runtime:
    """How evaluation reads Priming's policies (its `Method.runtime`): the composite on the history
    (`PrimedPolicy`, acting through `ape_jax.evaluate.history_policy`), the history policy's embedding probed. The
    weights are in the variables, so `settings` is not read."""
    return Runtime(apply=primed_model(cfg).apply)


def refusal(settings: Any, obs: str) -> str | None:
    """Why Priming cannot run under a sweep's settings (`Method.refuses`), or None."""
    if obs == "image":
        return (f"{NAME} runs on state observations (its key input is the current state: the prime network is "
                f"BC-SO's state MLP); --obs image is not supported")
    if settings.protocol.history < 2:
        return (f"{NAME} primes a history policy (protocol.history >= 2), got "
                f"protocol.history={settings.protocol.history}")
    return None   # without BC-SO among the methods under source bc-so: `Method.reads` (`methods.unread`)


def _learner(ctx) -> Learner:
    return make_priming(ctx.cfg, ctx.knobs_of(NAME).source)


methods.register(methods.Method(
    NAME, "Priming", grid=lambda ctx: [{"weight": w} for w in ctx.knobs_of(NAME).weights],
    hparams=lambda settings, lr, row: PrimingHparams.make(settings["weight"], lr=lr),
    program=NAME, learner=_learner, refuses=refusal, knobs=PrimingKnobs, runtime=policy_runtime, module=__name__,
    reads=lambda ctx: READS if ctx.knobs_of(NAME).source == "bc-so" else None))
