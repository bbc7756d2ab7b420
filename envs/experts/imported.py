"""Experts imported from a file: read, checked, converted, and kept outside the repository.

    python -m experiments.import_expert ~/Hopper-v1.pkl --env hopper --name cs294
    python -m experiments.sweep --set protocol.expert=cs294 --set protocol.labels=raw

An imported expert is the same deterministic MLP as a shipped one (`envs.experts`: `obs_mean`, `obs_std`,
`kernels`, `biases`, the card's `network.activation` and `network.head`), kept in the user's expert directory
`$APE_JAX_EXPERTS/<env>-<name>/` (default: `<envs.cache.cache_dir()>/experts/`), never in the
repository: its weights may carry another licence (the FCA repository's carry none). The directory holds the
converted parameters (`policy/`), `card.json` (source path, format, SHA-256, origin where known, the network,
the references under `brax`) and `references.json` (the references under the other protocols), measured at import.
A sweep selects it like a shipped variant, `--set protocol.expert=<name>`; shipped variants come first, and an
import whose name is a shipped variant's is refused.

Two formats are read:

**CS294 / FCA pickle** (`format: "cs294-pickle"`): the Berkeley CS294 expert policies, e.g. FCA's
`data/experts/Hopper-v1.pkl`, a dict

    {"nonlin_type": "tanh",
     "GaussianPolicy": {"obsnorm": {"Standardizer": {"mean_1_D": [1, D], "meansq_1_D": [1, D]}},
                        "hidden": {"FeedforwardNet": {<layer name>: {"AffineLayer": {"W": [in, out], "b": [1, out]}}}},
                        "out": {"AffineLayer": {"W": [H, A], "b": [1, A]}},
                        "logstdevs_1_Da": [1, A]}}

Hidden layers apply in sorted name order (as CS294's `load_policy` does), each followed by the `nonlin_type`
(`tanh`; `relu`); the observation is standardised as `(x − mean) / (sqrt(max(0, meansq − mean²)) + 1e-6)`; the
output layer is linear: the Gaussian's mean, unbounded (`head: "linear"`). The log-std is not used. It is read
with `safe_unpickle`, which builds numpy arrays and plain containers only and refuses any other global the
file names, unexecuted (pickles can run code on loading).

**NPZ MLP** (`format: "npz"`), for an expert from any framework (`numpy.savez`, no pickled objects):

| key | shape | meaning |
|---|---|---|
| `obs_mean`, `obs_std` | `[D]` | `x' = (x − obs_mean) / obs_std`, std > 0 (zeros and ones for none) |
| `kernel_0` … `kernel_{L−1}` | `[in, out]` | the affine layers, in order (`y = x @ kernel_i + bias_i`), L >= 1 |
| `bias_0` … `bias_{L−1}` | `[out]` | |
| `activation` | string | the hidden layers' nonlinearity: `tanh` or `relu` |
| `head` | string | `linear` or `tanh` (below) |

`head`: `linear`, the last layer's A outputs are the action (a Gaussian's mean, unbounded); `tanh`, tanh of its
first A outputs (A outputs, or 2A: a mean and a log-std, as Brax's and the shipped SAC networks give them), a
squashed policy's mode. E.g. from PyTorch (NumPy arrays of the tensors):

    np.savez(path, obs_mean=m, obs_std=s, kernel_0=l0.weight.T, bias_0=l0.bias, ..., activation="tanh",
             head="linear")

Either way the expert reads the environment's full observation (`env.expert_observation`, Brax's, which follows
gym's layout: `qpos[1:]` then `qvel`, the velocities clipped to ±10 for Hopper and Walker2d), so D must be its
size and A the action size, else the import is refused.
"""

from __future__ import annotations

import hashlib
import io
import os
import pathlib
import pickle
import re
import zipfile
import zlib
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from envs import experts

FORMATS = ("cs294-pickle", "npz")
NAME = re.compile(r"[a-z0-9_]+")  # `ape_jax.tasks.Protocol.expert`'s rule

# Files recognised by their SHA-256: where to get them, never shipped here (no licence).
KNOWN = {
    "56145a42b49fa5d7ca20bdc30407752a0830ee4cae882eccfd01e4fdddc4cf92": {
        "title": "CS294 Hopper-v1 expert, as the FCA paper used it",
        "origin": "https://github.com/AlvinWen428/fighting-copycat-agents (data/experts/Hopper-v1.pkl)",
        "env": "hopper"},
}


class ImportError_(ValueError):
    """A file that cannot be imported as an expert; the message (one line) names the file and the problem."""


def root() -> pathlib.Path:
    """The user's expert directory (`envs.experts.user_root`)."""
    return experts.user_root()


def sha256(path: pathlib.Path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


# -- the restricted unpickler ------------------------------------------------------------------------------------

try:
    from numpy._core.multiarray import _reconstruct as _numpy_reconstruct  # numpy 2
except ImportError:  # numpy 1
    from numpy.core.multiarray import _reconstruct as _numpy_reconstruct


class _Refused(pickle.UnpicklingError):
    """What the pickle asks for is refused (a global not admitted, an object array, a persistent reference), as
    opposed to bytes that are not a pickle at all (truncated or corrupt)."""


class _NdarrayClass:
    """Stands for `numpy.ndarray` in a pickle: only `_reconstruct` may use it (it cannot be called itself)."""


def _reconstruct(cls, shape, dtype):
    if cls is not _NdarrayClass:
        raise _Refused("numpy's _reconstruct builds numpy arrays only")
    return _numpy_reconstruct(np.ndarray, shape, _dtype(dtype))


def _dtype(spec, *args):
    dtype = np.dtype(spec, *args[:2])
    if dtype.hasobject:
        raise _Refused(f"numpy dtype {dtype} holds Python objects")
    return dtype


def _latin1(text, encoding="latin1"):
    # Python 3's protocol-2 pickles write bytes as _codecs.encode(str, "latin1"); nothing else is admitted
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise _Refused("_codecs.encode is admitted for latin-1 byte strings only")
    return text.encode("latin1")


_ADMITTED = {
    ("numpy.core.multiarray", "_reconstruct"): _reconstruct,   # numpy 1 (the file's own)
    ("numpy._core.multiarray", "_reconstruct"): _reconstruct,  # numpy 2's name for it
    ("numpy", "ndarray"): _NdarrayClass,
    ("numpy", "dtype"): _dtype,
    ("_codecs", "encode"): _latin1,
}
_PLAIN = (dict, list, tuple, str, bytes, int, float, bool, type(None))


class _Restricted(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        try:
            return _ADMITTED[(module, name)]
        except KeyError:
            raise _Refused(f"it names {module}.{name}") from None

    def persistent_load(self, pid):
        raise _Refused("it holds a persistent reference")


def _check_plain(x: Any, where: str = "") -> None:
    if isinstance(x, np.ndarray):
        if x.dtype.hasobject or not (np.issubdtype(x.dtype, np.number) or x.dtype == np.bool_
                                     or x.dtype.kind in "SU"):
            raise _Refused(f"{where or 'it'} is a {x.dtype} array")
        return
    if not isinstance(x, _PLAIN):
        raise _Refused(f"{where or 'it'} is a {type(x).__name__}")
    children = x.items() if isinstance(x, dict) else enumerate(x) if isinstance(x, (list, tuple)) else ()
    for k, v in children:
        if isinstance(x, dict) and not isinstance(k, (str, int)):
            raise _Refused(f"{where or 'it'} has a {type(k).__name__} key")
        _check_plain(v, f"{where}[{k!r}]")


def safe_unpickle(data: bytes, where: str = "<bytes>") -> Any:
    """The object a pickle holds, if it is numpy arrays (numeric) in plain containers (dict, list, tuple, str,
    numbers); anything else it would build is refused, never executed.

    Raises:
      ImportError_: one line naming `where` and what the pickle asked for, or that its bytes are no pickle
        (truncated or corrupt).
    """
    try:
        obj = _Restricted(io.BytesIO(data), encoding="latin1").load()
        _check_plain(obj)
    except _Refused as e:
        raise ImportError_(f"{where}: refused: only numpy arrays and plain containers are admitted, and "
                           f"{' '.join(str(e).split())} (nothing in it was executed)") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            MemoryError, OverflowError) as e:  # the bytes themselves: cut short, damaged, or no pickle at all
        raise ImportError_(f"{where}: not a readable pickle, truncated or corrupt "
                           f"({' '.join(str(e).split()) or type(e).__name__}); an expert file is a CS294 pickle "
                           "or an .npz MLP") from None
    return obj


# -- formats -----------------------------------------------------------------------------------------------------

class Converted(NamedTuple):
    """An expert read from a file, in the shipped experts' form (`envs.experts.policy_from_params`).

    Attributes:
      params: `obs_mean [D]`, `obs_std [D]`, `kernels` (`[in, out]` float32 each), `biases` (`[out]` each).
      activation: the hidden layers' (`envs.experts.ACTIVATIONS`).
      head: `"linear"` or `"tanh"` (`envs.experts.HEADS`).
      action_size: A.
    """

    params: dict
    activation: str
    head: str
    action_size: int

    @property
    def obs_size(self) -> int:
        return int(self.params["obs_mean"].shape[0])

    @property
    def hidden(self) -> list[int]:
        return [int(b.shape[0]) for b in self.params["biases"][:-1]]


def _get(tree: Any, path: tuple[str, ...], where: str) -> Any:
    node = tree
    for i, key in enumerate(path):
        if not isinstance(node, dict) or key not in node:
            raise ImportError_(f"{where}: not a CS294 policy pickle: no {'/'.join(path[:i + 1])}")
        node = node[key]
    return node


def _array(x: Any, name: str, where: str, ndim: int) -> np.ndarray:
    if not isinstance(x, np.ndarray) or not np.issubdtype(x.dtype, np.number) or x.ndim != ndim:
        raise ImportError_(f"{where}: {name} must be a {ndim}-d numeric array, got "
                           f"{getattr(x, 'dtype', type(x).__name__)}{list(np.shape(x))}")
    if not np.all(np.isfinite(x)):
        raise ImportError_(f"{where}: {name} holds non-finite values")
    return x.astype(np.float32)


def _check_chain(kernels: list[np.ndarray], biases: list[np.ndarray], names: list[str], d: int, where: str) -> None:
    width = d
    for k, b, name in zip(kernels, biases, names):
        if k.shape[0] != width or b.shape != (k.shape[1],):
            raise ImportError_(f"{where}: layer {name} has a {list(k.shape)} kernel and a {list(b.shape)} bias "
                               f"after {width} inputs: the layers do not chain")
        width = k.shape[1]


def read_cs294(path: pathlib.Path, action_size_hint: int | None = None) -> Converted:
    """The CS294 Gaussian policy in pickle `path` (module docstring), converted; `ImportError_` (one line)."""
    where = str(path)
    tree = safe_unpickle(pathlib.Path(path).read_bytes(), where)
    nonlin = _get(tree, ("nonlin_type",), where)
    if nonlin not in ("tanh", "relu"):
        raise ImportError_(f"{where}: nonlin_type {nonlin!r} is not supported; valid: tanh, relu")
    norm = _get(tree, ("GaussianPolicy", "obsnorm", "Standardizer"), where)
    mean = _array(_get(norm, ("mean_1_D",), where), "mean_1_D", where, 2)[0]
    meansq = _array(_get(norm, ("meansq_1_D",), where), "meansq_1_D", where, 2)[0]
    hidden = _get(tree, ("GaussianPolicy", "hidden", "FeedforwardNet"), where)
    if not isinstance(hidden, dict):
        raise ImportError_(f"{where}: GaussianPolicy/hidden/FeedforwardNet is not a dict of layers")
    names = sorted(hidden)
    layers = [_get(hidden, (n, "AffineLayer"), where) for n in names]
    layers.append(_get(tree, ("GaussianPolicy", "out", "AffineLayer"), where))
    names.append("out")
    kernels = [_array(_get(layer, ("W",), where), f"{n}/W", where, 2) for n, layer in zip(names, layers)]
    biases = [_array(_get(layer, ("b",), where), f"{n}/b", where, 2).reshape(-1) for n, layer in zip(names, layers)]
    if mean.shape != meansq.shape:
        raise ImportError_(f"{where}: mean_1_D {list(mean.shape)} and meansq_1_D {list(meansq.shape)} differ")
    _check_chain(kernels, biases, names, mean.shape[0], where)
    # CS294's load_policy: (x - mean) / (std + 1e-6), std = sqrt(max(0, E[x²] - E[x]²)); in float64, as stored
    std64 = np.sqrt(np.maximum(0.0, meansq.astype(np.float64) - np.square(mean.astype(np.float64)))) + 1e-6
    params = {"obs_mean": mean, "obs_std": std64.astype(np.float32), "kernels": kernels, "biases": biases}
    return Converted(params, str(nonlin), "linear", int(kernels[-1].shape[1]))


def read_npz(path: pathlib.Path, action_size_hint: int | None = None) -> Converted:
    """The MLP in `.npz` file `path` (module docstring's table), converted; `ImportError_` (one line).

    `action_size_hint`: the environment's A, which tells a tanh head of 2A outputs (a mean and a log-std) from one
    of A; without it the last layer's outputs are the actions."""
    where = str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:
        raise ImportError_(f"{where}: not a readable .npz file, truncated or corrupt "
                           f"({type(e).__name__}: {' '.join(str(e).split())})") from None
    missing = [k for k in ("obs_mean", "obs_std", "activation", "head", "kernel_0", "bias_0") if k not in arrays]
    numbered = sorted({int(m.group(2)) for k in arrays if (m := re.fullmatch(r"(kernel|bias)_(\d+)", k))})
    layers = len(numbered)
    gaps = [f"{kind}_{i}" for i in range(max(numbered, default=-1) + 1) for kind in ("kernel", "bias")
            if f"{kind}_{i}" not in arrays]
    if missing or gaps:
        raise ImportError_(f"{where}: missing layers or keys {', '.join(dict.fromkeys(missing + gaps))} (an npz "
                           "expert holds obs_mean, obs_std, kernel_0.., bias_0.., activation, head)")

    def text(key, valid):
        value = arrays[key]
        value = str(value.item()) if value.ndim == 0 and value.dtype.kind in "SU" else None
        if value not in valid:
            raise ImportError_(f"{where}: {key} must be one of {', '.join(valid)}, got {arrays[key]!r}")
        return value

    activation, head = text("activation", ("tanh", "relu")), text("head", ("linear", "tanh"))
    mean = _array(arrays["obs_mean"], "obs_mean", where, 1)
    std = _array(arrays["obs_std"], "obs_std", where, 1)
    if std.shape != mean.shape or np.any(std <= 0):
        raise ImportError_(f"{where}: obs_std must be positive and shaped like obs_mean {list(mean.shape)}")
    kernels = [_array(arrays[f"kernel_{i}"], f"kernel_{i}", where, 2) for i in range(layers)]
    biases = [_array(arrays[f"bias_{i}"], f"bias_{i}", where, 1) for i in range(layers)]
    _check_chain(kernels, biases, [str(i) for i in range(layers)], mean.shape[0], where)
    outputs = kernels[-1].shape[1]
    action_size = outputs
    if head == "tanh":
        # the shipped tanh networks have 2A outputs, the first A the mean: an A-output head is padded to that form
        if action_size_hint is not None and outputs == 2 * action_size_hint:
            action_size = action_size_hint
        else:
            kernels[-1] = np.concatenate([kernels[-1], np.zeros_like(kernels[-1])], axis=1)
            biases[-1] = np.concatenate([biases[-1], np.zeros_like(biases[-1])])
    params = {"obs_mean": mean, "obs_std": std, "kernels": kernels, "biases": biases}
    return Converted(params, activation, head, int(action_size))


READERS: dict[str, Callable[[pathlib.Path, int | None], Converted]] = {"cs294-pickle": read_cs294, "npz": read_npz}


def detect_format(path: pathlib.Path) -> str:
    """`"npz"` for a file that is a zip archive (what `numpy.savez` writes), else `"cs294-pickle"`."""
    with open(path, "rb") as f:
        return "npz" if f.read(4) == b"PK\x03\x04" else "cs294-pickle"


def read(path: pathlib.Path, fmt: str = "auto", action_size: int | None = None) -> Converted:
    """The expert in `path` (`fmt`: one of `FORMATS`, or `"auto"`: by its first bytes), converted; `action_size`:
    the environment's (`read_npz`'s hint).

    Raises:
      ImportError_: an unreadable file, a refused pickle, missing layers or layers that do not chain (one line).
    """
    path = pathlib.Path(path)
    if path.is_dir():
        raise ImportError_(f"{path} is a folder, not an expert file (a CS294 pickle or an .npz MLP)")
    if not path.is_file():
        raise ImportError_(f"{path} does not exist" if not path.exists() else f"{path} is not a regular file")
    fmt = detect_format(path) if fmt == "auto" else fmt
    if fmt not in READERS:
        raise ImportError_(f"unknown expert format {fmt!r}; valid: {', '.join(FORMATS)}")
    return READERS[fmt](path, action_size)


def check_fits(converted: Converted, env_name: str, obs_size: int, action_size: int, where: str) -> None:
    """Refuses (`ImportError_`, one line) an expert whose input is not `env_name`'s full observation or whose
    output is not its action."""
    if converted.obs_size != obs_size or converted.action_size != action_size:
        raise ImportError_(f"{where}: the expert reads {converted.obs_size} inputs and gives {converted.action_size} "
                           f"actions, but {env_name}'s full observation (gym's layout: qpos[1:], qvel) has "
                           f"{obs_size} and its actions {action_size}; pick the matching --env")


# -- the user's expert directory ---------------------------------------------------------------------------------

def source_info(path: pathlib.Path, fmt: str) -> dict:
    """What the card records of the file an expert came from: its path, format, size and SHA-256, and, for a
    file known by its SHA-256 (`KNOWN`), what it is and where to get it."""
    path = pathlib.Path(path).absolute()
    digest = sha256(path)
    known = KNOWN.get(digest, {})
    return {"path": str(path), "format": fmt, "bytes": path.stat().st_size, "sha256": digest,
            **{k: known[k] for k in ("title", "origin") if k in known}}


def card_for(env: str, name: str, converted: Converted, source: dict, command: str) -> dict:
    """The card of an imported expert `<env>-<name>` (`envs.experts.card` reads it); its references live in
    references.json, every protocol's (`brax` included)."""
    return {"algorithm": f"imported ({source['format']})", "env": env, "name": f"{env}-{name}", "source": source,
            "command": command,
            "network": {"obs_size": converted.obs_size, "hidden": converted.hidden,
                        "action_size": converted.action_size, "activation": converted.activation,
                        "head": converted.head}}


def install(env: str, name: str, converted: Converted, card: dict, references: dict[str, dict],
            base: pathlib.Path | None = None) -> pathlib.Path:
    """Writes the expert `<env>-<name>` into the user's expert directory (`base`, default `root()`): built in a
    hidden staging directory and renamed into place, so an interrupted import leaves any earlier one whole.

    Returns:
      The expert's directory.
    """
    import json
    import shutil

    base = pathlib.Path(base or root())
    base.mkdir(parents=True, exist_ok=True)
    target = base / f"{env}-{name}"
    staging = base / f".{target.name}.staging-{os.getpid()}"
    old = base / f".{target.name}.old-{os.getpid()}"
    try:
        experts.save(staging, converted.params, card)
        (staging / experts.REFERENCES).write_text(json.dumps(references, indent=2, sort_keys=True) + "\n")
        if target.exists():
            target.rename(old)
        staging.rename(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        shutil.rmtree(old, ignore_errors=True)
    return target
