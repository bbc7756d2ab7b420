"""ChannelDropout: the channel that leaks the expert's past dropped from the policy's input at random in training,
the ego-state dropout of driving planners, as a pure-functional `Learner`.

Two planners drop the input through which the past leaks into the prediction:

- ChauffeurNet (Bansal, Krizhevsky and Ogale, RSS 2019, "ChauffeurNet: Learning to Drive by Imitating the Best and
  Synthesizing the Worst"), "Past Motion Dropout" (§4.2 of the arXiv version as we recall its numbering): in 50% of
  the training examples the past-poses channel of the rendered input keeps only the current pose, so the network
  must explain the future from the scene and cannot extrapolate its own past motion (the paper's text, as we
  recall it; we could not check it here);
- PlanTF (Cheng, Chen, Mei, Yang, Li and Liu, ICRA 2024, "Rethinking Imitation-based Planner for Autonomous
  Driving"), its state dropout encoder (SDE) against the shortcut of the ego's kinematic state: in training each of
  the current ego state's kinematic tokens (velocity, acceleration, steering) is hidden from the encoder's attention
  independently per sample with probability 0.75, position and heading always visible; evaluation sees them all.
  The rate is the authors' released configuration (`jchengai/planTF`, `config/model/planTF.yaml`:
  `state_dropout: 0.75`, read in `StateAttentionEncoder`); we could not check whether the paper's text states it,
  nor its section number.

Here the channel is what carries the leak in the sweep's observation (`channels`):

- `prev_action`: the previous action that `protocol.prev_action` appends to every state observation
  (`ape_jax.observations.PreviousAction`: each frame is `[o, a_{t−1}]`, the action its last `action_dim` entries);
- `speed`: ToyTown's speed in its image observations, the measurement strip (`envs.toytown_render`: the top
  `strip_rows(height)` rows of the frame, every column and colour channel, grey as light as the car is fast);
- `auto` (the default): the one the observation carries, `prev_action` for vector observations and `speed` for
  frames (an observation never carries both: frames have no place for the previous action).

**Dropping** a channel of a sample zeroes it in every frame of the sample's history (the current one too), after
the history is gathered and before the augmentation and the policy's input scaling; each channel is drawn on its
own per sample, with probability `rate` (a traced knob, so the rates of `ChannelDropoutKnobs.rates` and the seeds
train in one `jit(vmap(scan))`). Zero is, for standardised states, the dimension's training mean (not a zero
action: the zeros a rollout shows at an episode's start standardise elsewhere), as HistoryDropout's zeros are;
for frames a black strip, which is exactly what ToyTown draws without the speed input (`speed_input=False`,
NoCrash's "w/o speed"). Evaluation, the loss analysis and the probes see every channel: the trained policy is a
plain `cfg.model()`. At rate 0 the learner is BC-OH's: the same initialisation and run key from the same key,
the same rows and augmentation (`ape_jax.baselines._batch`'s keys), the same loss and updates.

Defaults: `rates` (0.75,), PlanTF's; ChauffeurNet's 50% is `--set channel-dropout.rates=0.5` (or both: `=0.5,0.75`).
Where ours differs: both planners drop part of a structured input (a rendered channel, attention tokens) and
keep the current pose; we zero a whole channel of a flat observation or of a frame. PlanTF draws each of its
three kinematic tokens apart; `speed` is one channel here (their velocity token). The loss is the project's
(`learner.action_errors`), not a trajectory loss.

Refusals (`refusal`, checked when the sweep's spec is made, before anything is collected or compiled): a channel
the sweep's observation does not carry: `prev_action` without `protocol.prev_action` (or on frames), `speed` on
state observations or where the protocol does not show it (`protocol.speed_input` true: ToyTown's `nocrash`
protocols; a task without the setting refuses it in one line when the spec resolves it).

Metrics (`[n]` float32 per `run` of `n` iterations): `"loss"` and `"unweighted_loss"` (the BC loss, unweighted:
the two are equal) and `"dropped"` (the share of the batch's samples with a channel dropped).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ape_jax import methods
from ape_jax.baselines._batch import OWN_KEYS, errors
from ape_jax.history import history_index
from ape_jax.knobs import nonnegative, positive
from ape_jax.learner import (Data, Learner, LearnerConfig, augment, gradient_step, learning_rate, make_train,
                             policy_apply, scanned_learner, trainable)
from envs.toytown_render import strip_rows

NAME = "channel-dropout"
CHANNELS = ("prev_action", "speed")   # what `channels` may name (and "auto")
AUTO = "auto"
DEFAULT_RATE = 0.75   # PlanTF's released config: config/model/planTF.yaml, state_dropout: 0.75


def _rate(name: str, value: float) -> None:
    """Refuses (`ValueError`, one line) a drop probability outside [0, 1]."""
    nonnegative(name, value)
    if value > 1.0:
        raise ValueError(f"{name} must be <= 1 (a probability), got {value}")


@dataclasses.dataclass(frozen=True)
class ChannelDropoutKnobs:
    """ChannelDropout's own settings (`--set channel-dropout.KNOB=VALUE`; the module docstring).

    Attributes:
      channels: which channel to drop: `"prev_action"`, `"speed"`, several joined by commas, or `"auto"` (the one
        the observation carries). A string, so the command line, results.json and a smoke run read it whole.
      rates: a grid axis: each training sample's probability of having a channel dropped (PlanTF: 0.75).
    """

    channels: str = AUTO
    rates: tuple[float, ...] = (DEFAULT_RATE,)

    def __post_init__(self):
        if not isinstance(self.channels, str):
            raise ValueError(f"{NAME}.channels must be a string ({AUTO!r}, or {', '.join(CHANNELS)} joined by "
                             f"commas), got {self.channels!r}")
        names = [c.strip() for c in self.channels.split(",")]
        valid = names == [AUTO] or (all(c in CHANNELS for c in names) and len(set(names)) == len(names))
        if not valid:
            raise ValueError(f"{NAME}.channels must be {AUTO!r} or {', '.join(CHANNELS)} (each once, joined by "
                             f"commas), got {self.channels!r}")
        if not self.rates or len(set(self.rates)) != len(self.rates):
            raise ValueError(f"{NAME}.rates must list each rate once, at least one, got {self.rates!r}")
        for r in self.rates:
            _rate(f"{NAME}.rates", r)

    def names(self, images: bool) -> tuple[str, ...]:
        """The channels dropped from an observation of frames (`images`) or vectors: `auto` resolved."""
        if self.channels.strip() == AUTO:
            return ("speed",) if images else ("prev_action",)
        return tuple(c.strip() for c in self.channels.split(","))


@struct.dataclass
class ChannelDropoutHparams:
    """Traced knobs of one ChannelDropout run (stack them along a leading axis for seeds × rates)."""

    rate: jax.Array   # [] float32, a sample's probability of having a channel dropped; 0 = BC-OH
    lr: jax.Array     # [] float32

    @classmethod
    def make(cls, rate: float = DEFAULT_RATE, lr: float = 2e-4) -> ChannelDropoutHparams:
        """Validated hyperparameters (`ValueError`, one line, for a value out of range)."""
        _rate(f"{NAME} rate", rate)
        positive("learning rate", lr)
        return cls(rate=jnp.float32(rate), lr=jnp.float32(lr))


@struct.dataclass
class ChannelDropoutState:
    """The scan carry: BC-OH's policy variables, Adam moments, step and run key."""

    params: Any          # cfg.model() variables
    opt_state: Any       # on trainable(params)
    step: jax.Array      # [] int32
    key: jax.Array


def channel_masks(cfg: LearnerConfig, names: tuple[str, ...]) -> np.ndarray:
    """`[C, *obs_shape] bool`: where each channel of `names` lies in one observation of `cfg.obs_shape`.

    Raises:
      ValueError: a channel this observation's shape has no place for (`prev_action` on frames or on a vector no
        longer than an action, `speed` on vectors), in one line.
    """
    masks = []
    for name in names:
        mask = np.zeros(cfg.obs_shape, bool)
        if name == "prev_action":
            if cfg.images or cfg.obs_shape[0] <= cfg.action_dim:
                raise ValueError(f"{NAME}: prev_action is the last {cfg.action_dim} entries of a vector observation "
                                 f"followed by the previous action; observations of shape {cfg.obs_shape} have none")
            mask[-cfg.action_dim:] = True
        elif name == "speed":
            if not cfg.images:
                raise ValueError(f"{NAME}: speed is the measurement strip of ToyTown's frames; observations of shape "
                                 f"{cfg.obs_shape} are not frames")
            mask[:strip_rows(cfg.obs_shape[0])] = True
        else:
            raise ValueError(f"{NAME}: unknown channel {name!r}; valid: {', '.join(CHANNELS)}")
        masks.append(mask)
    return np.stack(masks)


def drop_channels(key: jax.Array, history: jax.Array, masks: np.ndarray | jax.Array, rate: jax.Array | float
                  ) -> tuple[jax.Array, jax.Array]:
    """Each sample's channels zeroed in every frame of its history, each with probability `rate`.

    Args:
      key: the draws' randomness.
      history: `[B, H, *obs_shape]` observations (standardised float32 states, or uint8 frames).
      masks: `[C, *obs_shape] bool`, the channels (`channel_masks`).
      rate: the probability of dropping each channel of a sample, in [0, 1] (traced); 0 returns `history` as is.

    Returns:
      `(history with the drawn channels zeroed [B, H, *obs_shape], which were dropped [B, C] bool)`.
    """
    masks = jnp.asarray(masks)
    dropped = jax.random.uniform(key, (history.shape[0], masks.shape[0])) < rate
    hit = jnp.any(dropped.reshape(dropped.shape + (1,) * (masks.ndim - 1)) & masks[None], axis=1)  # [B, *obs_shape]
    return jnp.where(hit[:, None], jnp.zeros((), history.dtype), history), dropped


def make_channel_dropout(cfg: LearnerConfig, channels: str = AUTO) -> Learner:
    """The pure functions of ChannelDropout for one static setup (the module docstring).

    Args:
      cfg: shapes, counts and the recipe (`cfg.model()` the policy, state or image).
      channels: the channels to drop, as `ChannelDropoutKnobs.channels` reads them: names of `CHANNELS` joined by
        commas, or `"auto"` (`speed` for frames, `prev_action` for vectors).

    Returns:
      A `Learner` whose `init` and run key are `make_train(cfg)`'s: at rate 0 it trains BC-OH's policy on BC-OH's
      batches with BC-OH's loss and updates.
    """
    names = ChannelDropoutKnobs(channels).names(cfg.images)
    masks = channel_masks(cfg, names)
    base = make_train(cfg)
    model, adam = cfg.model(), cfg.optimizer()

    def init(key: jax.Array, hp: ChannelDropoutHparams, data: Data) -> ChannelDropoutState:
        key_init, key_run = jax.random.split(key)  # as make_train: the same policy and batches for the same key
        params = base.init_policy(key_init, data)
        return ChannelDropoutState(params=params, opt_state=adam.init(trainable(params)),
                                   step=jnp.zeros((), jnp.int32), key=key_run)

    def update(state: ChannelDropoutState, hp: ChannelDropoutHparams, data: Data):
        key_step = jax.random.fold_in(state.key, state.step)
        _, idx = data.sample(key_step, cfg.batch_size)   # BC-OH's rows (`_batch.sample_batch`'s keys)
        history, dropped = drop_channels(jax.random.fold_in(key_step, OWN_KEYS),
                                         data.obs[history_index(data.t, idx, cfg.history)], masks, hp.rate)
        x = base.policy_input(augment(cfg, jax.random.fold_in(key_step, 2), history))
        action = data.action[idx]

        def loss_fn(variables):
            predicted, variables = policy_apply(model, variables, x, train=True)
            bc = jnp.mean(errors(cfg, predicted, action))
            return bc, (bc, variables)

        params, opt_state, loss, _ = gradient_step(adam, state.params, state.opt_state,
                                                   learning_rate(cfg, hp.lr, state.step), loss_fn)
        state = state.replace(params=params, opt_state=opt_state, step=state.step + 1)
        return state, {"loss": loss, "unweighted_loss": loss,
                       "dropped": jnp.mean(jnp.any(dropped, axis=1).astype(jnp.float32))}

    return scanned_learner(cfg, base, init, update)


def refusal(settings: Any, obs: str) -> str | None:
    """Why ChannelDropout cannot run under a sweep's settings (`Method.refuses`): a channel its observation does not
    carry (the module docstring), or None."""
    knobs = methods.knobs_of(NAME, getattr(settings, "knobs", None) or {})
    images = obs == "image"
    for name in knobs.names(images):
        if name == "prev_action" and images:
            return (f"{NAME} drops prev_action, which frames do not carry (protocol.prev_action is for vector "
                    f"observations); use --set {NAME}.channels=speed on ToyTown's frames")
        if name == "prev_action" and not settings.protocol.prev_action:
            return (f"{NAME} drops prev_action, which --obs {obs} carries only with the previous action in view: "
                    f"--set protocol.prev_action=true")
        if name == "speed" and not images:
            return (f"{NAME} drops speed, the measurement strip of ToyTown's frames: --obs image (--obs {obs} has "
                    f"no strip)")
        if name == "speed" and settings.protocol.speed_input is not True:
            shown = settings.protocol.speed_input
            return (f"{NAME} drops speed, which the frames show only where the protocol says so: "
                    f"protocol.speed_input=true (ToyTown's nocrash protocol), got {str(shown).lower()}")
    return None


methods.register(methods.Method(
    NAME, "ChannelDropout", grid=lambda ctx: [{"rate": r} for r in ctx.knobs_of(NAME).rates],
    hparams=lambda settings, lr, row: ChannelDropoutHparams.make(settings["rate"], lr=lr),
    program=NAME, learner=lambda ctx: make_channel_dropout(ctx.cfg, ctx.knobs_of(NAME).channels),
    refuses=refusal, knobs=ChannelDropoutKnobs, module=__name__))
