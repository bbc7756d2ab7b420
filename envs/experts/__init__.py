"""The experts shipped with ape_jax, and the files they live in.

Each MuJoCo expert is a deterministic MLP acting on the **full** Brax
observation, trained by `python -m experiments.train_expert --env NAME` and
committed as two files under `envs/experts/NAME/`:

- `policy/` — an orbax checkpoint of the parameters: `obs_mean [D]`,
  `obs_std [D]`, `kernels` (a list of `[in, out]` float32 matrices) and
  `biases` (a list of `[out]` vectors);
- `card.json` — how it was made and how good it is: algorithm, hyperparameters,
  environment steps, wall time, hardware, the network spec and the return over
  100 episodes next to a random policy's.

The network is `a = tanh(first action_size outputs of MLP((obs - mean) / std))`
with ReLU hidden layers, the mode of the SAC policy (the card's `network.head`
`"tanh"`, the default). A Gaussian policy with an unbounded mean (the FCA paper's
CS294 experts, the shipped rough experts) has `network.head` `"linear"`: its last
layer has `action_size` outputs and the action is that mean, unbounded; the
environment clips what it executes. It is evaluated here
from the parameters alone, so loading needs neither Brax's `load_policy` nor
its network classes:

    policy = envs.experts.load("hopper")   # jit-able: [..., D] -> [..., A]
    action = jax.jit(policy)(state.info["brax_obs"])

ToyCar's expert is the rule-based one, `envs.toycar.expert_action`.

Imported experts (`envs.experts.imported`, `python -m experiments.import_expert`) have the same files in the
user's expert directory (`user_root()`), never in the repository; every function here finds a name
`<env>-<variant>` among the shipped experts first, then among the imported ones.

An unbounded expert's action (a `"linear"` head) is its label; what the environment executes is that action
clipped to the action bounds (`executed`), as the FCA code did (the reward's control cost reads the action
given, so it must be clipped before the step).
"""

from __future__ import annotations

import json
import os
import pathlib
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

ROOT = pathlib.Path(__file__).parent
CARD = "card.json"
POLICY = "policy"
REFERENCES = "references.json"  # the expert's and a random policy's returns under other protocols


class ExpertError(RuntimeError):
    """A missing or unreadable expert; the message names the file and the command that trains it."""


def _variant(name: str) -> tuple[str, str]:
    """`"hopper-ppo" -> ("hopper", "ppo")`, `"hopper" -> ("hopper", "")`: an expert's environment and variant."""
    env, _, variant = name.partition("-")
    return env, variant


def train_command(name: str) -> str:
    env, variant = _variant(name)
    return f"python -m experiments.train_expert --env {env}" + (f" --algorithm {variant}" if variant else "")


def import_command(name: str) -> str:
    env, variant = _variant(name)
    return f"python -m experiments.import_expert PATH --env {env} --name {variant or 'NAME'}"


def user_root() -> pathlib.Path:
    """The user's expert directory, where imported experts live: `$APE_JAX_EXPERTS`, else
    `<envs.cache.cache_dir()>/experts`."""
    if os.environ.get("APE_JAX_EXPERTS"):
        return pathlib.Path(os.environ["APE_JAX_EXPERTS"])
    from envs.cache import cache_dir

    return cache_dir() / "experts"


def available() -> tuple[str, ...]:
    """Names of the environments with a shipped expert (a card on disk)."""
    return tuple(sorted(p.parent.name for p in ROOT.glob(f"*/{CARD}")))


def imported_names() -> tuple[str, ...]:
    """Names (`<env>-<variant>`) of the imported experts in the user's expert directory (`user_root()`)."""
    base = user_root()
    return tuple(sorted(p.parent.name for p in base.glob(f"*/{CARD}"))) if base.is_dir() else ()


def is_imported(name: str) -> bool:
    """Whether `name` resolves to an imported expert (no shipped one of that name, an imported card)."""
    return not (ROOT / name / CARD).is_file() and (user_root() / name / CARD).is_file()


def directory(name: str) -> pathlib.Path:
    """The directory of expert `name`: the shipped one (`envs/experts/<name>/`), else the imported one of that name
    if it exists, else the shipped path (where error messages point)."""
    if is_imported(name):
        return user_root() / name
    return ROOT / name


def executed(policy: Callable[[jax.Array], jax.Array], bounds: tuple[jax.Array, jax.Array]
             ) -> Callable[[jax.Array], jax.Array]:
    """`policy`'s action as the environment executes it: clipped to `bounds` (`env.action_bounds`, `[A]` each); a
    no-op for a tanh head within them."""
    low, high = bounds
    return lambda obs: jnp.clip(policy(obs), low, high)


def card(name: str, root: pathlib.Path | None = None) -> dict:
    """The expert's card (see the module docstring) as a dict.

    Raises:
      ExpertError: no card, or one that is not valid JSON with a `network` spec.
    """
    path = (root or directory(name)) / CARD
    if not path.is_file():
        raise ExpertError(f"no expert for {name!r}: {path} does not exist; train one with "
                          f"`{train_command(name)}`, or import one with `{import_command(name)}`")
    try:
        data = json.loads(path.read_text())
        net = data["network"]
        head = net.get("head", "tanh")
        if head not in HEADS:
            raise ValueError(f"network.head {head!r} is not one of {', '.join(HEADS)}")
        outputs = int(net["action_size"]) * (2 if head == "tanh" else 1)
        sizes = [int(net["obs_size"]), *map(int, net["hidden"]), outputs]
    except (ValueError, KeyError, TypeError) as e:
        raise ExpertError(f"corrupt expert card {path}: {type(e).__name__}: {e}; retrain with "
                          f"`{train_command(name)}`") from e
    data["network"]["layer_sizes"] = sizes
    return data


def reference_command(name: str, protocol: str) -> str:
    env, variant = _variant(name)
    return (f"python -m experiments.expert_references --env {env}" + (f" --expert {variant}" if variant else "")
            + f" --protocol {protocol}")


def reference(name: str, protocol: str = "brax", root: pathlib.Path | None = None) -> dict:
    """The returns to normalise by under `protocol`: `return_mean`, `return_std`, `random_return_mean`, `episodes`.

    `"brax"` (the setting the expert was trained and measured at) reads its card; any other protocol
    reads `references.json` beside it, written by `experiments.expert_references`.

    Raises:
      ExpertError: no card, or no reference for the protocol (naming the command that measures it).
    """
    data = card(name, root)
    if protocol == "brax" and "return_mean" in data:
        return {k: data[k] for k in ("return_mean", "return_std", "random_return_mean", "episodes") if k in data}
    path = (root or directory(name)) / REFERENCES
    try:
        refs = json.loads(path.read_text()) if path.is_file() else {}
        ref = refs.get(protocol)
        if ref is not None:
            return {k: float(ref[k]) if k != "episodes" else int(ref[k])
                    for k in ("return_mean", "return_std", "random_return_mean", "episodes")}
    except (ValueError, KeyError, TypeError, AttributeError) as e:
        raise ExpertError(f"corrupt expert references {path}: {type(e).__name__}: {e}; measure them again with "
                          f"`{reference_command(name, protocol)}`") from e
    raise ExpertError(f"{name}'s expert has no reference returns under protocol {protocol!r} ({path}); measure "
                      f"them with `{reference_command(name, protocol)}`")


def save(out: pathlib.Path, params: dict, card_data: dict) -> None:
    """Writes an expert (`params` as in the module docstring) and its card into directory `out`.

    The parameters are written first and the card last, so a directory with a
    card always holds a complete expert.
    """
    import shutil

    import orbax.checkpoint as ocp

    out = pathlib.Path(out).absolute()
    out.mkdir(parents=True, exist_ok=True)
    (out / CARD).unlink(missing_ok=True)
    if (out / POLICY).exists():
        shutil.rmtree(out / POLICY)
    tree = jax.tree.map(np.asarray, params)
    with ocp.StandardCheckpointer() as ckpt:
        ckpt.save(out / POLICY, tree)
    tmp = out / (CARD + ".tmp")
    tmp.write_text(json.dumps(card_data, indent=2, sort_keys=True) + "\n")
    tmp.replace(out / CARD)


def load_params(name: str, root: pathlib.Path | None = None) -> dict:
    """The expert's parameters, checked against its card's network spec.

    Raises:
      ExpertError: missing files, an unreadable checkpoint, or shapes or values
        that disagree with the card (the message names the file).
    """
    import orbax.checkpoint as ocp

    root = root or directory(name)
    sizes = card(name, root)["network"]["layer_sizes"]
    path = (root / POLICY).absolute()
    abstract = {
        "obs_mean": jax.ShapeDtypeStruct((sizes[0],), jnp.float32),
        "obs_std": jax.ShapeDtypeStruct((sizes[0],), jnp.float32),
        "kernels": [jax.ShapeDtypeStruct((a, b), jnp.float32) for a, b in zip(sizes[:-1], sizes[1:])],
        "biases": [jax.ShapeDtypeStruct((b,), jnp.float32) for b in sizes[1:]],
    }
    if not path.is_dir():
        raise ExpertError(f"no expert parameters for {name!r}: {path} does not exist; train them with "
                          f"`{train_command(name)}`")
    try:
        with ocp.StandardCheckpointer() as ckpt:
            params = ckpt.restore(path, abstract)
    except Exception as e:  # orbax raises many types for damaged files
        raise ExpertError(f"corrupt expert checkpoint {path}: {type(e).__name__}: {str(e)[:300]}; "
                          f"retrain with `{train_command(name)}`") from e
    got = jax.tree.map(lambda x: tuple(np.shape(x)), params)
    want = jax.tree.map(lambda x: x.shape, abstract)
    if got != want:
        raise ExpertError(f"corrupt expert checkpoint {path}: parameter shapes {got} do not match the "
                          f"card's network {sizes}; retrain with `{train_command(name)}`")
    if not all(bool(np.all(np.isfinite(x))) for x in jax.tree.leaves(params)):
        raise ExpertError(f"corrupt expert checkpoint {path}: non-finite parameters; retrain with "
                          f"`{train_command(name)}`")
    return jax.tree.map(jnp.asarray, params)


ACTIVATIONS = {"relu": jax.nn.relu, "tanh": jnp.tanh}  # the hidden layers' (the card's `network.activation`)
# the output layer (the card's `network.head`): "tanh" squashes the first half of the outputs (a tanh-Gaussian's
# mode: SAC, Brax's PPO); "linear" is a Gaussian's mean, as many outputs as actions, unbounded
HEADS = ("tanh", "linear")


def policy_from_params(params: dict, activation: str = "relu", head: str = "tanh") -> Callable[[jax.Array], jax.Array]:
    """A deterministic policy `obs [..., D] float -> action [..., A] float32`, its hidden layers' `activation` one
    of `ACTIVATIONS` (SAC's experts: relu; PPO's and CS294's: tanh) and its output `head` one of `HEADS` (`"tanh"`:
    in [-1, 1]; `"linear"`: the unbounded mean of a Gaussian policy)."""
    if activation not in ACTIVATIONS:
        raise ExpertError(f"unknown expert activation {activation!r}; valid: {', '.join(ACTIVATIONS)}")
    if head not in HEADS:
        raise ExpertError(f"unknown expert head {head!r}; valid: {', '.join(HEADS)}")
    act, n_layers = ACTIVATIONS[activation], len(params["kernels"])

    def policy(obs: jax.Array) -> jax.Array:
        x = (jnp.asarray(obs, jnp.float32) - params["obs_mean"]) / params["obs_std"]
        for i, (k, b) in enumerate(zip(params["kernels"], params["biases"])):
            x = x @ k + b
            if i < n_layers - 1:
                x = act(x)
        return x if head == "linear" else jnp.tanh(x[..., : x.shape[-1] // 2])

    return policy


def load(name: str, root: pathlib.Path | None = None) -> Callable[[jax.Array], jax.Array]:
    """The shipped expert of environment `name` as a jit-able `obs -> action`.

    Args:
      name: an environment with an expert (`available()`), e.g. `"hopper"`, or a variant shipped beside
        it, `"<env>-<variant>"` (e.g. `"hopper-ppo"`: `ape_jax.tasks.Protocol.expert`).
      root: a directory holding `card.json` and `policy/` instead of the
        shipped one (e.g. a freshly trained expert).

    Returns:
      `policy(obs)`: `obs [..., D] float32` (the full Brax observation,
      `env.expert_observation(state)`) to `action [..., A] float32`.

    Raises:
      ExpertError: a missing or corrupt checkpoint, naming the file and the
        command that trains it.
    """
    net = card(name, root)["network"]
    return policy_from_params(load_params(name, root), net.get("activation", "relu"), net.get("head", "tanh"))

