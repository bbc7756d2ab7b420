"""Demonstrations as Minari datasets, and any Minari dataset as demonstrations.

Minari (Farama Foundation) is the standard format for offline-RL and
imitation data. A Minari dataset lives in a directory `ROOT/<dataset_id>/data/`
(`metadata.json` plus `main_data.hdf5`); `ROOT` is Minari's datasets root,
`$MINARI_DATASETS_PATH` or `~/.minari/datasets`. Here the root is always an
explicit argument first (`root=`), so nothing is written to the home directory
unless asked; `minari.load_dataset(id)` finds our datasets when
`MINARI_DATASETS_PATH` names the same root.

    path = to_minari(demos, meta, "hopper-pos-v0", root="datasets")    # datasets/hopper-pos-v0
    demos = from_minari(path)                       # or from_minari("hopper-pos-v0", root="datasets")

Mapping between the formats, per episode of `T` steps (Minari stores one
episode per group; ours are rows of a flat table grouped by `episode`):

| `Demonstrations` (`T` rows)     | Minari episode                                                |
|---------------------------------|---------------------------------------------------------------|
| `obs [T, ...]`                  | `observations [T+1, ...]`: Minari also keeps the observation   |
|                                 | after the last step, which we never record; export repeats    |
|                                 | the last row, import drops the final row                      |
| `action [T, A]` (clean labels)  | `actions [T, A]`                                              |
| `reward [T]`                    | `rewards [T]`                                                 |
| `done [T]` (termination)        | `terminations [T]`                                            |
| (episode ended, not `done`)     | `truncations [T]`: True at the last step of an episode that  |
|                                 | did not terminate; import ignores it                          |
| `t [T]`                         | `infos["t"] [T+1]` = 0..T; import rebuilds `t` = 0..T-1      |
| `episode [T]`                   | `infos["episode"] [T+1]`; the Minari episode id for others'   |
| `executed [T, A]`               | `infos["executed"] [T+1, A]` (last row repeated); others':    |
|                                 | `executed = action`                                          |
| `sim`                           | not exported; import leaves it empty                          |
| metadata dict (`meta`)          | the dataset's metadata key `"ape_jax"`                        |

So `from_minari(to_minari(demos, ...))` equals `demos` exactly on every field
but `sim`, with the same dtypes (tested for state and image observations).

Spaces written: uint8 observations (images) `Box(0, 255, uint8)`, float
observations `Box(-inf, inf, float32)`; actions `Box(low, high, float32)` with
the environment's action bounds when given (and the data lies within them),
else unbounded. Images are stored raw: Minari 0.5.4 JPEG-encodes uint8 image
observations (>= 32x32) by default, which is lossy; we turn that off so the
round trip is exact (at the price of uncompressed frames on disk).

Importing someone else's dataset: observations must be a `Box` (flat states,
or images kept uint8; other dtypes become float32); `Dict`/`Tuple`/other
observation spaces are refused. Actions may be a `Box` (flattened to `[T, A]`
float32) or `Discrete(n)` (one-hot, `[T, n]`, so APE is the squared error of
the predicted action distribution). Everything is validated like
`ape_jax.pipeline.data.load` (finite values, shapes, episode structure); any problem is
a `DataError` whose one-line message names the path.

Writing is all or nothing: the dataset is built in a hidden staging directory
under the root and renamed into place, so an interrupted export never leaves a
dataset that loads.
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import shutil
import tempfile
import warnings

import numpy as np

from ape_jax.pipeline import data as data_lib
from ape_jax.pipeline.data import DataError, Demonstrations

META_KEY = "ape_jax"
_METADATA = "metadata.json"


def datasets_root(root: str | os.PathLike | None = None) -> pathlib.Path:
    """Minari's datasets root: `root`, else `$MINARI_DATASETS_PATH`, else `~/.minari/datasets`."""
    if root is not None:
        return pathlib.Path(root)
    if os.environ.get("MINARI_DATASETS_PATH"):
        return pathlib.Path(os.environ["MINARI_DATASETS_PATH"])
    return pathlib.Path.home() / ".minari" / "datasets"


def check_dataset_id(dataset_id: str) -> None:
    """Refuses an id Minari cannot load with a one-line `ValueError`: ids read `(namespace/)name-v<N>`."""
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        parse_dataset_id(dataset_id)
    except (ValueError, TypeError):  # Minari raises TypeError when the version is missing
        raise ValueError(f"invalid Minari dataset id {dataset_id!r}: ids read '(namespace/)name-v<N>', "
                         "e.g. 'hopper-pos-v0'") from None


@contextlib.contextmanager
def _minari_root(root: pathlib.Path):
    # Minari's writers take the root from the environment only; set it for the call.
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _spaces(demos: Demonstrations, action_bounds):
    import gymnasium as gym

    obs = np.asarray(demos.obs)
    action = np.asarray(demos.action, np.float32)
    if obs.dtype == np.uint8:
        obs_space = gym.spaces.Box(0, 255, obs.shape[1:], np.uint8)
    else:
        obs_space = gym.spaces.Box(-np.inf, np.inf, obs.shape[1:], np.float32)
    low, high = np.full(action.shape[1], -np.inf, np.float32), np.full(action.shape[1], np.inf, np.float32)
    if action_bounds is not None:
        b_low, b_high = (np.broadcast_to(np.asarray(b, np.float32), low.shape) for b in action_bounds)
        if np.all(action >= b_low) and np.all(action <= b_high):
            low, high = b_low, b_high
    return obs_space, gym.spaces.Box(low, high, low.shape, np.float32)


def _buffers(demos: Demonstrations) -> list:
    from minari.data_collector import EpisodeBuffer

    obs, action = np.asarray(demos.obs), np.asarray(demos.action, np.float32)
    executed = np.asarray(demos.executed, np.float32)
    episode, done = np.asarray(demos.episode), np.asarray(demos.done)
    reward = np.asarray(demos.reward, np.float32)
    starts = np.flatnonzero(np.r_[True, episode[1:] != episode[:-1]])
    buffers = []
    for start, stop in zip(starts, np.r_[starts[1:], len(episode)]):
        rows = slice(start, stop)
        last = lambda x: np.concatenate([x[rows], x[stop - 1:stop]])  # noqa: E731  T+1 rows
        terminated = done[rows] > 0
        truncated = np.zeros_like(terminated)
        truncated[-1] = not terminated[-1]
        buffers.append(EpisodeBuffer(
            observations=last(obs), actions=action[rows], rewards=reward[rows],
            terminations=terminated, truncations=truncated,
            infos={"t": np.arange(stop - start + 1, dtype=np.int32),
                   "episode": np.full(stop - start + 1, episode[start], np.int32),
                   "executed": last(executed)}))
    return buffers


def to_minari(demos: Demonstrations, meta: dict | None, dataset_id: str,
              root: str | os.PathLike | None = None, *, action_bounds=None, overwrite: bool = False,
              ref_min_score: float | None = None, ref_max_score: float | None = None) -> pathlib.Path:
    """Writes `demos` as a local Minari dataset (hdf5), one Minari episode per episode.

    Args:
      demos: the demonstrations (`obs [N, ...]` uint8 or float, `action [N, A]`, ...).
      meta: JSON-able metadata (e.g. `ape_jax.pipeline.data.load`'s), stored under the
        dataset metadata key `"ape_jax"`; may be None.
      dataset_id: Minari id, `(namespace/)name-v<N>`.
      root: Minari datasets root (see `datasets_root`).
      action_bounds: `(low, high)` of the environment's actions (`env.action_bounds`),
        each `[A]` or scalar; the action space is unbounded without them.
      overwrite: replace an existing dataset of that id instead of refusing.
      ref_min_score, ref_max_score: a random policy's and the expert's mean episode return under the dataset's
        protocol (`collect.reference_returns`), stored as Minari's reference scores so that
        `minari.get_normalized_score(dataset, returns)` gives (return − random) ÷ (expert − random), the
        normalisation of this project's tables; give both or neither.

    Returns:
      The dataset's directory, `root/dataset_id` (load it with `from_minari`).

    Raises:
      ValueError: an invalid id, metadata that is not JSON-able, or one reference score without the other (or
        scores that are not finite, or equal).
      FileExistsError: the dataset exists and `overwrite` is False.
    """
    import minari

    check_dataset_id(dataset_id)
    refs = {}
    if (ref_min_score is None) != (ref_max_score is None):
        raise ValueError("to_minari: give both reference scores (ref_min_score and ref_max_score) or neither")
    if ref_min_score is not None:
        low, high = float(ref_min_score), float(ref_max_score)
        if not (np.isfinite(low) and np.isfinite(high) and low != high):
            raise ValueError(f"to_minari: reference scores must be finite and differ, got {low} and {high}")
        refs = {"ref_min_score": low, "ref_max_score": high}
    if len(demos) == 0:
        raise ValueError("to_minari: no transitions to export")
    try:
        meta_json = json.loads(json.dumps(meta or {}))
    except (TypeError, ValueError) as e:
        raise ValueError(f"to_minari: metadata must be JSON-able: {e}") from None
    root = datasets_root(root)
    target = root / dataset_id
    if target.exists() and not overwrite:
        raise FileExistsError(f"{target}: a Minari dataset of id {dataset_id!r} exists already")
    obs_space, action_space = _spaces(demos, action_bounds)
    root.mkdir(parents=True, exist_ok=True)
    staging = pathlib.Path(tempfile.mkdtemp(prefix=".staging-", dir=root))  # hidden: Minari's listing skips it
    try:
        with _minari_root(staging), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Minari warns about each optional field left out (author, ...)
            dataset = minari.create_dataset_from_buffers(
                dataset_id, _buffers(demos), observation_space=obs_space, action_space=action_space,
                algorithm_name="expert",
                description="Expert demonstrations exported by ape_jax (ape_jax.pipeline.minari_io).",
                data_format="hdf5", jpeg_encoding=False)
            dataset.storage.update_metadata({META_KEY: meta_json, **refs})
        # a namespace is a directory with a metadata file: keep those Minari made
        parts = pathlib.PurePosixPath(dataset_id).parts[:-1]
        for level in (pathlib.Path(*parts[:i]) for i in range(1, len(parts) + 1)):
            made = staging / level / "namespace_metadata.json"
            (root / level).mkdir(exist_ok=True)
            if made.is_file() and not (root / level / made.name).exists():
                shutil.copyfile(made, root / level / made.name)
        if target.exists():
            target.rename(staging / ".replaced")
        os.replace(staging / dataset_id, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return target


def resolve(path_or_id: str | os.PathLike, root: str | os.PathLike | None = None) -> pathlib.Path:
    """The data directory (holding `metadata.json`) of a dataset given by path or by id.

    `path_or_id` is a dataset directory (`.../<id>`), its `data/` directory, or
    a dataset id under `root` (see `datasets_root`).

    Raises:
      DataError: nothing there, or a directory that is not a Minari dataset.
    """
    path = pathlib.Path(path_or_id)
    candidates = [path] if path.is_absolute() or path.exists() else [path, datasets_root(root) / path]
    for c in candidates:
        if (c / "data" / _METADATA).is_file():
            return c / "data"
        if (c / _METADATA).is_file():
            return c
    if path.is_dir():
        raise DataError(f"{path}: not a Minari dataset (no data/{_METADATA} inside)")
    if path.exists():
        raise DataError(f"{path}: not a Minari dataset (a file; Minari datasets are directories)")
    raise DataError(f"{path}: no such Minari dataset (neither a directory nor a dataset id under "
                    f"{datasets_root(root)})")


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _check_metadata(data_dir: pathlib.Path, where: str) -> None:
    # Minari reads metadata.json with bare asserts and key lookups; name what is wrong instead.
    try:
        meta = json.loads((data_dir / _METADATA).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{where}: not a readable Minari dataset ({_one_line(e)} in {_METADATA})") from None
    if not isinstance(meta, dict):
        raise DataError(f"{where}: not a Minari dataset ({_METADATA} holds a {type(meta).__name__}, not an object)")
    missing = [k for k in ("data_format", "total_episodes") if k not in meta]
    if "env_spec" not in meta:  # without the spaces Minari makes the environment to read them from
        missing += [k for k in ("observation_space", "action_space") if k not in meta]
    if missing:
        raise DataError(f"{where}: not a Minari dataset ({_METADATA} lacks {', '.join(missing)})")


def from_minari(path_or_id: str | os.PathLike, root: str | os.PathLike | None = None) -> Demonstrations:
    """Reads a Minari dataset (ours or anyone's) as `Demonstrations`, validated.

    Args:
      path_or_id: the dataset's directory, its `data/` directory, or its id under `root`.
      root: Minari datasets root for ids (see `datasets_root`).

    Returns:
      `Demonstrations` (NumPy arrays) with `obs`, `action`, `executed`,
      `episode`, `t`, `done`, `reward` (mapping in the module docstring);
      `sim` is empty.

    Raises:
      DataError: one line naming the path: missing, not a Minari dataset,
        unsupported spaces, inconsistent or non-finite data.
    """
    import gymnasium as gym

    data_dir = resolve(path_or_id, root)
    where = str(data_dir.parent if data_dir.name == "data" else data_dir)
    _check_metadata(data_dir, where)
    try:
        import minari

        dataset = minari.MinariDataset(data_dir)
    except (ValueError, KeyError, TypeError, AttributeError, AssertionError, OSError, ImportError,
            gym.error.Error) as e:
        raise DataError(f"{where}: not a readable Minari dataset ({_one_line(e)})") from e
    obs_space, action_space = dataset.observation_space, dataset.action_space
    if not isinstance(obs_space, gym.spaces.Box):
        raise DataError(f"{where}: only Box observation spaces are supported, this dataset has "
                        f"{type(obs_space).__name__} observations")
    if not isinstance(action_space, (gym.spaces.Box, gym.spaces.Discrete)):
        raise DataError(f"{where}: only Box or Discrete action spaces are supported, this dataset has "
                        f"{type(action_space).__name__} actions")
    ours = isinstance(dataset.storage.metadata.get(META_KEY), dict)
    columns = {k: [] for k in ("obs", "action", "executed", "episode", "t", "done", "reward")}
    try:
        for ep in dataset.iterate_episodes():
            n = len(ep.rewards)
            obs, actions = np.asarray(ep.observations), np.asarray(ep.actions)
            if n < 1 or len(obs) != n + 1 or len(actions) != n or len(ep.terminations) != n:
                raise DataError(f"{where}: episode {ep.id} has {len(obs)} observations, {len(actions)} actions, "
                                f"{n} rewards and {len(ep.terminations)} terminations; Minari episodes have T+1 "
                                "observations and T of the rest, T >= 1")
            label = _labels(actions, action_space, f"{where}: episode {ep.id}")
            infos = ep.infos or {}
            executed = np.asarray(infos.get("executed", label), np.float32)[:n] if ours else label
            episode = int(np.asarray(infos["episode"])[0]) if ours and "episode" in infos else int(ep.id)
            columns["obs"].append(obs[:n].reshape(n, -1) if obs.ndim == 1 else obs[:n])
            columns["action"].append(label)
            columns["executed"].append(executed if executed.shape == label.shape else label)
            columns["episode"].append(np.full(n, episode, np.int32))
            columns["t"].append(np.arange(n, dtype=np.int32))
            columns["done"].append(np.asarray(ep.terminations, np.float32))
            columns["reward"].append(np.asarray(ep.rewards, np.float32))
        if not columns["obs"]:
            raise DataError(f"{where}: the Minari dataset has no episodes")
        arrays = {k: np.concatenate(v) for k, v in columns.items()}
    except DataError:
        raise
    except (ValueError, KeyError, TypeError, IndexError, AttributeError, AssertionError, OSError) as e:
        raise DataError(f"{where}: unreadable Minari episodes ({_one_line(e)})") from e
    if arrays["obs"].dtype != np.uint8:
        arrays["obs"] = arrays["obs"].astype(np.float32)
    return data_lib.from_arrays(arrays, where=where)


def _labels(actions: np.ndarray, space, where: str) -> np.ndarray:
    """`[T, A] float32` action labels: a Box flattened, a `Discrete(n)` one-hot."""
    import gymnasium as gym

    if isinstance(space, gym.spaces.Box):
        return np.asarray(actions, np.float32).reshape(len(actions), -1)
    index = np.asarray(actions).reshape(-1).astype(np.int64) - int(space.start)
    if np.any((index < 0) | (index >= space.n)):
        raise DataError(f"{where}: actions outside the action space {space}")
    return np.eye(int(space.n), dtype=np.float32)[index]


def dataset_settings(spec: str | os.PathLike, fmt: str = "auto") -> dict | None:
    """The collection settings a dataset records (the project's `NAME.json` `settings`), or None where it has none
    (a Minari dataset, or your own data): what says which protocol it was collected under."""
    if fmt == "auto":
        fmt = "npz" if str(spec).endswith((".npz", ".json")) else "minari"
    if fmt != "npz":
        return None
    try:
        meta = json.loads(data_lib.meta_path(pathlib.Path(spec).with_suffix(".npz")).read_text())
    except (OSError, ValueError):
        return None
    settings = meta.get("settings") if isinstance(meta, dict) else None
    return settings if isinstance(settings, dict) else None


def dataset_metadata(spec: str | os.PathLike, fmt: str = "auto") -> dict | None:
    """What a dataset named on a command line says about itself: the project's metadata (`NAME.json`, or the
    `"ape_jax"` key of a Minari dataset this project exported: collection `settings`, which name its expert, and
    recorded `references`), with a Minari dataset's own `ref_min_score` / `ref_max_score` as its `references`
    (`random_return_mean`, `return_mean`) where the project's metadata records none; None where it says nothing
    readable.
    """
    if fmt == "auto":
        fmt = "npz" if str(spec).endswith((".npz", ".json")) else "minari"
    try:
        if fmt == "npz":
            meta = json.loads(data_lib.meta_path(pathlib.Path(spec).with_suffix(".npz")).read_text())
            return meta if isinstance(meta, dict) else None
        outer = json.loads((resolve(spec) / _METADATA).read_text())
    except (OSError, ValueError, DataError):
        return None
    if not isinstance(outer, dict):
        return None
    meta = dict(outer.get(META_KEY)) if isinstance(outer.get(META_KEY), dict) else {}
    low, high = outer.get("ref_min_score"), outer.get("ref_max_score")
    if "references" not in meta and isinstance(low, (int, float)) and isinstance(high, (int, float)):
        meta["references"] = {"return_mean": float(high), "return_std": None, "random_return_mean": float(low),
                              "source": "minari ref_min_score / ref_max_score"}
    return meta or None


def load_dataset(spec: str | os.PathLike, fmt: str = "auto") -> tuple[Demonstrations, str]:
    """`(demos, where)` of a dataset named on a command line: the project's `NAME.npz`, or a Minari directory or id.

    `fmt`: `"npz"`, `"minari"`, or `"auto"` (names ending in .npz or .json are
    the project's format, anything else Minari). Raises `DataError` (one line).
    """
    if fmt == "auto":
        fmt = "npz" if str(spec).endswith((".npz", ".json")) else "minari"
    if fmt == "npz":
        path = pathlib.Path(spec).with_suffix(".npz")
        if path != pathlib.Path(spec) and not path.exists():  # named by its metadata: the message names what was typed
            raise DataError(f"{spec}: no such dataset file (a dataset is NAME.npz with its NAME.json beside it, and "
                            f"{path.name} is not there)")
        return data_lib.load(path)[0], str(path)
    path = resolve(spec)
    return from_minari(path), str(path.parent if path.name == "data" else path)
