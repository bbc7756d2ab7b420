"""Trains an expert: `python -m experiments.train_expert --env hopper`.

Soft actor-critic (`ape_jax.experts.sac`, built from Brax's SAC parts) on the
**full** observation of the MJX environment. Every `epoch_steps` environment
steps the run evaluates its deterministic policy (Brax's Evaluator, 16
episodes), keeps the best one and checkpoints everything (networks, optimiser
states, temperature, replay buffer, best policy) with orbax under `--workdir`;
running the same command again resumes there. At the end, or as soon as the
evaluation return passes `--stop-at`, the best policy is measured over
`--eval-episodes` episodes of `envs.make(env, obs="full")` and exported with its
card to `envs/experts/<env>/` (see `envs.experts`).

`--algorithm ppo` and `--algorithm rough` train with Brax's PPO instead, in one
go without checkpoints, and export the best evaluated policy to
`envs/experts/<env>-ppo/` or `envs/experts/<env>-rough/`: rough is the kind of
expert the FCA paper's MuJoCo numbers came from (a 64×64 tanh policy whose
normal's mean, unbounded, is the label; card `network.head` "linear"), trained
at frame skip 4; `--set NAME=VALUE` changes one of its settings (entropy_cost,
init_noise_std, ...). `experiments.expert_stats` measures how rough the result is.

The per-task hyperparameters below are the ones the shipped experts were
trained with; their cards repeat them.

Bad input is refused with one line on stderr and exit status 2 before anything
is compiled: an unknown env, counts below 1, a NaN `--stop-at`, a `--workdir`
or `--out` that cannot be written, or a checkpoint in `--workdir` that is
corrupt or was written with other settings (it is left in place), a `--set` that names no setting or
gives a value of the wrong type.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys
import time

from experiments._cli import Parser, fail, unwritable

TARGETS = {"hopper": 2500.0, "walker2d": 3000.0, "halfcheetah": 4000.0}  # returns of 1000-step episodes

# Standard SAC settings (batch 256, 256x256 MLPs, gamma 0.99, lr 3e-4) with an
# update-to-data ratio of 0.5: on a 2-core CPU one update costs ~4 ms and an
# environment step far less, so half as many updates per step buys twice the
# data for the same wall time (~470 env steps/s). Runs stop early at --stop-at.
_SAC = dict(num_envs=64, grad_updates_per_step=32, epoch_steps=25_600)
CONFIGS = {
    "hopper": dict(_SAC, num_timesteps=2_000_000),
    "walker2d": dict(_SAC, num_timesteps=2_000_000),
    "halfcheetah": dict(_SAC, num_timesteps=1_500_000),
}


# `--algorithm ppo`: an expert of the kind the FCA paper's MuJoCo experts are (a 64×64 tanh Gaussian policy from
# PPO), shipped beside the SAC one as `envs/experts/<env>-ppo` (`ape_jax.tasks.Protocol.expert`). Brax's PPO with
# the classic MuJoCo settings (2,048 steps per update from 64 environments, 4 minibatches, 10 epochs, Adam 3e-4,
# γ 0.99, GAE λ 0.95, clip 0.2, no entropy bonus, normalised observations, a 64×64 tanh value network).
PPO = dict(num_timesteps=3_000_000, num_envs=64, unroll_length=32, batch_size=16, num_minibatches=4,
           num_updates_per_batch=10, learning_rate=3e-4, entropy_cost=0.0, discounting=0.99, gae_lambda=0.95,
           clipping_epsilon=0.2, reward_scaling=1.0, normalize_observations=True, episode_length=1000,
           num_evals=31, num_eval_envs=16, hidden_layer_sizes=(64, 64))
# `--algorithm rough`: an expert of the CS294 kind FCA's MuJoCo numbers came from (`envs/experts/<env>-rough`): the
# same PPO, but a plain normal policy, unsquashed, with a state-independent (learned) std; the label is its mean,
# unbounded (the environment clips what it executes), exported with the card's `network.head` "linear". Trained at
# frame skip 4 on every task (gym's Hopper and Walker2d; HalfCheetah's Brax default is 5), within 30 minutes of a
# 2-core CPU. A small entropy bonus (0.003) and 3M steps: of the Hopper candidates measured (docs/design.md, "Rough
# experts"), the one whose labels' statistics came closest to FCA's expert's.
ROUGH = dict(PPO, num_timesteps=3_000_000, num_evals=21, entropy_cost=0.003, distribution_type="normal",
             noise_std_type="log", init_noise_std=1.0, frame_skip=4)
ALGORITHMS = ("sac", "ppo", "rough")
OUTPUTS = {"tanh": "tanh of the first action_size outputs",
           "linear": "the normal's mean: action_size outputs, unbounded (the environment clips what it executes)"}


def parse(argv=None) -> argparse.Namespace:
    import envs

    p = Parser(prog="python -m experiments.train_expert", description=__doc__.splitlines()[0])
    p.add_argument("--env", required=True, help="a Brax environment (hopper, walker2d, halfcheetah, ...)")
    p.add_argument("--algorithm", default="sac", choices=ALGORITHMS,
                   help="sac (the shipped experts, envs/experts/<env>), ppo (a 64x64 tanh policy, "
                        "envs/experts/<env>-ppo) or rough (a 64x64 tanh normal policy whose unbounded mean is the "
                        "label, at frame skip 4, envs/experts/<env>-rough); ppo and rough train in one go, without "
                        "checkpoints")
    p.add_argument("--steps", type=int, default=None, help="environment steps in all (default: per task)")
    p.add_argument("--stop-at", type=float, default=None,
                   help="stop once the 16-episode evaluation return reaches this (default: 1.1 x the target)")
    p.add_argument("--workdir", type=pathlib.Path, default=None,
                   help="checkpoints; an existing one is resumed (default: runs/experts/<env>)")
    p.add_argument("--fresh", action="store_true", help="discard the checkpoint in --workdir and start over")
    p.add_argument("--out", type=pathlib.Path, default=None,
                   help="where the expert is exported (default: envs/experts/<env>, the shipped one)")
    p.add_argument("--eval-episodes", type=int, default=100, help="episodes for the final measurement")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="ppo and rough: change one of their settings (e.g. entropy_cost=0.01, init_noise_std=0.5); "
                        "repeatable")
    args = p.parse_args(argv)
    from ape_jax import tasks

    trainable = [n for n in envs.names() if tasks.get(n).expert == "shipped"]
    if args.env in envs.names() and args.env not in trainable:
        fail(p, f"{args.env}'s expert is rule-based (the environment's own `expert`); nothing to train")
    if args.env not in envs.names():
        fail(p, f"unknown env {args.env!r}; valid: {', '.join(trainable)}")
    if args.steps is not None and args.steps < 1:
        fail(p, f"--steps must be >= 1, got {args.steps}")
    if args.eval_episodes < 1:
        fail(p, f"--eval-episodes must be >= 1, got {args.eval_episodes}")
    if args.stop_at is not None and math.isnan(args.stop_at):
        fail(p, "--stop-at must be a number (inf: never stop early), got nan")
    if args.set and args.algorithm == "sac":
        fail(p, "--set applies to --algorithm ppo or rough")
    if args.algorithm != "sac":
        ppo_settings(args)   # refuses a bad --set before anything is compiled
    name = args.env if args.algorithm == "sac" else f"{args.env}-{args.algorithm}"
    args.workdir = args.workdir or pathlib.Path("runs/experts") / name
    if args.out is None:
        from envs import experts

        args.out = experts.directory(name)
    for flag, path in (("--workdir", args.workdir), ("--out", args.out)):
        if path.exists() and not path.is_dir():
            fail(p, f"{flag} {path} is a file; it must be a directory")
        why = unwritable(path)
        if why:
            fail(p, f"{flag} {path}: cannot write there: {why}")
    return args


def make_config(args):
    from ape_jax.experts.sac import SACConfig

    kw = dict(CONFIGS.get(args.env, {}), seed=args.seed)
    if args.steps is not None:  # a short run: shrink the warm-up and the epoch to fit
        num_envs = kw.get("num_envs", SACConfig.num_envs)
        kw["num_timesteps"] = args.steps
        kw["min_replay_size"] = min(SACConfig.min_replay_size, args.steps // 2)
        kw["epoch_steps"] = min(kw.get("epoch_steps", SACConfig.epoch_steps), -(-args.steps // num_envs) * num_envs)
    return SACConfig(**kw)


def main(argv=None) -> int:
    args = parse(argv)
    if args.algorithm in ("ppo", "rough"):
        return train_ppo(args)
    import jax
    import jax.numpy as jnp
    from tqdm import tqdm

    import envs
    from ape_jax.experts.sac import Checkpoints, make_trainer, run_epoch

    cfg = make_config(args)
    env = envs.make(args.env, obs="full", episode_length=cfg.episode_length)
    trainer = make_trainer(env.brax_env, cfg)
    ckpt = Checkpoints(args.workdir / "ckpt", trainer, cfg)
    if args.fresh:
        ckpt.clear()
    try:
        restored = ckpt.restore()
    except ValueError as e:
        return fail(None, f"--workdir {args.workdir}: {e}; use the same settings, another --workdir, or --fresh "
                    "(which discards it)")
    if restored is not None:
        state, best, meta = restored
        print(f"resuming {args.workdir} at {int(state.env_steps):,} env steps "
              f"(best evaluation return so far {meta['best_return']:.1f})")
    else:
        t0 = time.perf_counter()
        state = trainer.prefill(trainer.init(jax.random.PRNGKey(cfg.seed)))
        best = jax.tree.map(jnp.copy, state.policy)
        meta = dict(ckpt.new_meta(), wall_s=time.perf_counter() - t0)
    stop_at = args.stop_at if args.stop_at is not None else 1.1 * TARGETS.get(args.env, float("inf"))
    with tqdm(total=cfg.num_timesteps, initial=int(state.env_steps), unit="step", unit_scale=True,
              desc=f"SAC {args.env}", dynamic_ncols=True) as bar:
        while int(state.env_steps) < cfg.num_timesteps and meta["best_return"] < stop_at:
            state, best, meta = run_epoch(trainer, state, best, meta)
            ckpt.save(state, best, meta)
            bar.update(int(state.env_steps) - bar.n)
            bar.set_postfix(ret=f"{meta['history'][-1]['return']:.0f}", best=f"{meta['best_return']:.0f}")
    ckpt.close()
    return export(args, cfg, env, trainer.policy_spec(best), meta)


def train_ppo(args) -> int:
    """`--algorithm ppo` / `rough`: Brax's PPO with `PPO`'s / `ROUGH`'s settings (`--steps`, `--seed`, `--set`
    apply), evaluated `num_evals` times (deterministic, `num_eval_envs` episodes), the best evaluated policy exported
    as `export` does: ppo's a tanh-Gaussian's mode, rough's the normal's mean, unbounded."""
    import envs

    cfg = ppo_settings(args)
    env = envs.make(args.env, obs="full", episode_length=cfg.episode_length,
                    **({} if cfg.frame_skip is None else {"n_frames": cfg.frame_skip}))
    params, meta = run_ppo(env.brax_env, cfg, desc=f"{args.algorithm.upper()} {args.env}")
    if params is None:
        return fail(None, "PPO evaluated no policy; raise --steps")
    stop_at = args.stop_at if args.stop_at is not None else math.inf
    if meta["best_return"] < stop_at < math.inf:
        print(f"best evaluation return {meta['best_return']:.1f} stayed below --stop-at {stop_at:g}")
    if cfg.distribution_type == "normal":
        return export(args, cfg, envs.make(args.env, obs="full", episode_length=cfg.episode_length), params, meta,
                      algorithm="PPO (brax.training.agents.ppo, normal policy: unsquashed, state-independent std)",
                      activation="tanh", head="linear")
    return export(args, cfg, env, params, meta, algorithm="PPO (brax.training.agents.ppo, tanh Gaussian policy)",
                  activation="tanh")


def ppo_settings(args) -> PpoSettings:
    """The run's `PpoSettings`: `ROUGH` or `PPO`, then `--steps`, `--seed` and each `--set NAME=VALUE` (`fail`s with
    one line for an unknown name or a value of the wrong type)."""
    kw = dict(ROUGH if args.algorithm == "rough" else PPO, seed=args.seed)
    if args.steps is not None:
        kw["num_timesteps"] = args.steps
    types = {f.name: f.type for f in dataclasses.fields(PpoSettings)}
    settable = sorted(set(types) - {"seed", "num_timesteps", "hidden_layer_sizes"})
    for item in args.set or ():
        name, sep, value = item.partition("=")
        if not sep or name not in settable:
            fail(None, f"--set {item!r}: expected NAME=VALUE, NAME one of {', '.join(settable)}")
        kw[name] = _parse_value(item, types[name], value)
    try:
        return PpoSettings(**kw)
    except ValueError as e:
        fail(None, str(e))


def _parse_value(item: str, kind: str, value: str):
    """`--set`'s VALUE as a field of type `kind` (the dataclass field's annotation: "int", "float", "bool", ...)."""
    if kind == "bool":
        if value.lower() not in ("true", "false", "1", "0"):
            fail(None, f"--set {item!r}: {value!r} is not true or false")
        return value.lower() in ("true", "1")
    try:
        return float(value) if kind == "float" else int(value) if kind.startswith("int") else value
    except ValueError:
        fail(None, f"--set {item!r}: {value!r} is not {'a number' if kind == 'float' else 'an integer'}")


def run_ppo(brax_env, cfg: PpoSettings, desc: str = "PPO") -> tuple[dict | None, dict]:
    """Trains with Brax's PPO (`brax.training.agents.ppo.train`) on `brax_env` under `cfg`.

    Returns:
      (params, meta): the best evaluated policy as `envs.experts` parameters (`obs_mean [D]`, `obs_std [D]`,
      `kernels`, `biases`; None if nothing was evaluated) and `meta`: `best_return`, `best_step`, `history`
      (`env_steps`, `return` per evaluation), `wall_s`, `cpu_s` (this process's CPU time) and, for a normal policy,
      `policy_std` (the learned std per action dim at the best policy).
    """
    import functools

    import jax.numpy as jnp
    import numpy as np
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo
    from tqdm import tqdm

    kw = dataclasses.asdict(cfg)
    hidden = tuple(kw.pop("hidden_layer_sizes"))
    net_kw = {k: kw.pop(k) for k in ("distribution_type", "noise_std_type", "init_noise_std")}
    kw.pop("frame_skip")  # the environment's, already applied
    meta = {"best_return": -math.inf, "best_step": 0, "history": [], "wall_s": 0.0}
    latest, best = {}, {}
    t0, c0 = time.perf_counter(), time.process_time()
    bar = tqdm(total=kw["num_timesteps"], unit="step", unit_scale=True, desc=desc, dynamic_ncols=True)

    def keep(step, make_policy, params):   # called with each evaluated policy, before its evaluation
        latest.update(step=int(step), normalizer=params[0], policy=params[1])

    def progress(step, metrics):
        ret = float(metrics.get("eval/episode_reward", math.nan))
        meta["history"].append({"env_steps": int(step), "return": ret})
        if ret > meta["best_return"] and latest.get("step") == int(step):
            meta.update(best_return=ret, best_step=int(step))
            best.update(latest)
        bar.update(int(step) - bar.n)
        bar.set_postfix(ret=f"{ret:.0f}", best=f"{meta['best_return']:.0f}")

    network = functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=hidden,
                                value_hidden_layer_sizes=hidden, activation=jnp.tanh, **net_kw)
    ppo.train(environment=brax_env, network_factory=network, deterministic_eval=True,
              progress_fn=progress, policy_params_fn=keep, **kw)
    bar.close()
    meta.update(wall_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)
    if not best:
        return None, meta
    params = export_params(best["normalizer"], best["policy"], net_kw["distribution_type"])
    if net_kw["distribution_type"] == "normal":
        log_std = best["policy"]["params"]["std_logparam"]["log_value"]
        meta["policy_std"] = [round(float(x), 4) for x in np.exp(np.asarray(log_std))]
    return params, meta


def export_params(normalizer, policy: dict, distribution_type: str) -> dict:
    """Brax PPO's observation normaliser (running statistics) and policy network parameters as `envs.experts`
    parameters: `obs_mean [D]`, `obs_std [D]`, `kernels` and `biases` in layer order (a normal policy's last layer
    is its mean, `[64, A]`; a tanh-normal's outputs the mean and the std, `[64, 2A]`)."""
    import jax.numpy as jnp

    layers = policy["params"]
    if distribution_type == "normal":   # {"MLP_0": {"hidden_i"}, "Dense_0": the mean, "std_logparam"}
        hidden = layers["MLP_0"]
        order = [hidden[n] for n in sorted(hidden, key=lambda n: int(n.rsplit("_", 1)[1]))] + [layers["Dense_0"]]
    else:                               # {"hidden_i"}: the last one outputs the mean and the std
        order = [layers[n] for n in sorted(layers, key=lambda n: int(n.rsplit("_", 1)[1]))]
    return {"obs_mean": jnp.asarray(normalizer.mean, jnp.float32), "obs_std": jnp.asarray(normalizer.std, jnp.float32),
            "kernels": [jnp.asarray(layer["kernel"], jnp.float32) for layer in order],
            "biases": [jnp.asarray(layer["bias"], jnp.float32) for layer in order]}


@dataclasses.dataclass(frozen=True)
class PpoSettings:
    """`PPO`'s or `ROUGH`'s settings as the card records them (`export` reads `episode_length` and
    `hidden_layer_sizes`). `distribution_type` "tanh_normal" (ppo) or "normal" (rough: `noise_std_type` "log" learns
    a state-independent log std starting at `init_noise_std`); `frame_skip` None: the task's Brax default."""

    num_timesteps: int
    num_envs: int
    unroll_length: int
    batch_size: int
    num_minibatches: int
    num_updates_per_batch: int
    learning_rate: float
    entropy_cost: float
    discounting: float
    gae_lambda: float
    clipping_epsilon: float
    reward_scaling: float
    normalize_observations: bool
    episode_length: int
    num_evals: int
    num_eval_envs: int
    seed: int
    hidden_layer_sizes: tuple
    distribution_type: str = "tanh_normal"
    noise_std_type: str = "scalar"
    init_noise_std: float = 1.0
    frame_skip: int | None = None

    def __post_init__(self):
        if self.distribution_type not in ("normal", "tanh_normal"):
            raise ValueError(f"distribution_type must be normal or tanh_normal, got {self.distribution_type!r}")
        if self.noise_std_type not in ("scalar", "log"):
            raise ValueError(f"noise_std_type must be scalar or log, got {self.noise_std_type!r}")
        if not self.init_noise_std > 0 or (self.frame_skip is not None and self.frame_skip < 1):
            raise ValueError(f"init_noise_std must be > 0 and frame_skip >= 1, got {self.init_noise_std} and "
                             f"{self.frame_skip}")


def export(args, cfg, env, params, meta, algorithm: str = "SAC (ape_jax.experts.sac, from brax.training's SAC parts)",
           activation: str = "relu", head: str = "tanh") -> int:
    """Measures the best policy over `--eval-episodes` episodes of `env` (the `brax` protocol's setting, which the
    card's returns are the references of) and writes it with its card."""
    import jax

    from envs import experts
    from experiments._measure import expert_and_random_returns
    from experiments._timing import machine

    out = args.out
    print(f"measuring the best policy (evaluation return {meta['best_return']:.1f} at "
          f"{meta['best_step']:,} steps) over {args.eval_episodes} episodes ...")
    policy = experts.policy_from_params(params, activation, head)
    measured = expert_and_random_returns(env, policy, args.eval_episodes, jax.random.PRNGKey(cfg.seed + 2))
    target = TARGETS.get(args.env)
    card = {
        "env": args.env, "obs": "full", "algorithm": algorithm,
        "hyperparameters": dataclasses.asdict(cfg),
        "env_steps": meta["best_step"], "env_steps_trained": meta["history"][-1]["env_steps"] if meta["history"] else 0,
        "wall_s": round(meta["wall_s"], 1),
        **({"cpu_s": round(meta["cpu_s"], 1)} if "cpu_s" in meta else {}),
        "hardware": machine(),
        "network": {"obs_size": int(params["obs_mean"].shape[0]), "action_size": int(env.action_size),
                    "hidden": list(cfg.hidden_layer_sizes), "activation": activation,
                    "head": head, "output": OUTPUTS[head], "normalize_observations": True,
                    **({"policy_std": meta["policy_std"]} if "policy_std" in meta else {})},
        "measured_at": {"frame_skip": env.frame_skip, "episode_length": env.episode_length},
        "episode_length": cfg.episode_length, "target_return": target,
        **measured,
        "training_curve": [{"env_steps": h["env_steps"], "return": round(h["return"], 1)} for h in meta["history"]],
        "versions": _versions(),
    }
    experts.save(out, params, card)
    verdict = "" if target is None else (" (target met)" if measured["return_mean"] >= target
                                          else f" (below the target {target:.0f})")
    print(f"{args.env}: return {measured['return_mean']:.1f} ± {measured['return_std']:.1f} over "
          f"{args.eval_episodes} episodes{verdict}; random policy {measured['random_return_mean']:.1f}; "
          f"written to {out}")
    return 0


def _versions() -> dict:
    from importlib.metadata import version

    return {p: version(p) for p in ("jax", "brax", "mujoco", "mujoco-mjx", "flax", "optax", "orbax-checkpoint")}


if __name__ == "__main__":
    sys.exit(main())
