"""Expert demonstrations: the `Demonstrations` pytree, its split by episode, its files.

A dataset is a flat table of transitions, episodes concatenated in order, each
episode's rows contiguous with time index `t = 0, 1, ...`. Histories are built
by index at batch time (`ape_jax.history.history_index`), never by copying frames.

On disk a dataset is two files side by side (the format is documented in
`README.md`):

- `NAME.npz` — compressed NumPy arrays: `obs`, `action`, `executed`, `episode`,
  `t`, `done`, `reward`, and `sim/<field>` for the simulator state;
- `NAME.json` — metadata: environment, observation mode, expert card, seed,
  noise, library versions, shapes, and the `.npz` file's SHA-256.

`save` writes the arrays first and the metadata last, each through a temporary
file renamed into place, so an interrupted write never leaves a dataset that
loads. `load` refuses, with a `DataError` naming the file and the problem,
anything that is not a complete, consistent dataset: a missing or truncated
file, a checksum mismatch, missing keys, wrong shapes or dtypes, mismatched
lengths, non-finite values, or broken episode structure.
"""

from __future__ import annotations

import dataclasses

import hashlib
import json
import os
import pathlib
import zipfile
from typing import Any, NamedTuple

import jax
import numpy as np
from flax import struct

from envs.cache import cache_dir  # noqa: F401  (the pipeline's name for it: `data.cache_dir()`)

FORMAT = 1
REQUIRED = ("obs", "action", "episode", "t", "done", "reward")


class DataError(ValueError):
    """A dataset file that cannot be used; the message names the file and the problem."""


class Split(NamedTuple):
    """A dataset split by episode."""

    train: Demonstrations
    val: Demonstrations


@dataclasses.dataclass(frozen=True)
class Part:
    """One part of a split: rows of whole episodes.

    `demos` holds whole episodes (the context histories and ψ's past actions read); `rows` `[N] int64` are the
    part's own rows in it, or None for all of them. A split by episode has `rows=None` (its episodes are the
    part); a split by rows (the FCA code's) keeps every collected episode and names its rows.
    """

    demos: Demonstrations
    rows: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.demos) if self.rows is None else int(len(self.rows))

    def own(self, x) -> np.ndarray:
        """A per-row array of `demos` (e.g. `demos.obs`) at the part's rows."""
        return np.asarray(x) if self.rows is None else np.asarray(x)[self.rows]

    @property
    def obs(self) -> np.ndarray:
        return self.own(self.demos.obs)

    @property
    def action(self) -> np.ndarray:
        return self.own(self.demos.action)

    @property
    def num_episodes(self) -> int:
        """Episodes the part's rows come from."""
        return int(len(np.unique(self.own(self.demos.episode))))


def split_parts(demos: Demonstrations, kind: str, train: int | None, val: int | None, val_frac: float = 0.2,
                seed: int = 0) -> tuple[Part, Part]:
    """The training and validation `Part`s of `demos`, as a protocol says.

    `kind="rows"`: a fixed random permutation (seed `seed`) of all rows; its first `train` rows train and the
    next `val` validate (the FCA code's `random_split`). `kind="episodes"`: `demos.split_sizes(train, val)`, or
    `demos.split(val_frac)` when no sizes are given. Raises `ValueError` for too few rows.
    """
    if kind == "rows":
        if len(demos) < train + val:
            raise ValueError(f"{len(demos):,} transitions, fewer than the {train:,} + {val:,} the split needs; "
                             "collect more episodes")
        perm = np.random.default_rng(seed).permutation(len(demos))
        return Part(demos, np.sort(perm[:train])), Part(demos, np.sort(perm[train:train + val]))
    if kind != "episodes":
        raise ValueError(f"unknown split {kind!r}; valid: rows, episodes")
    parts = demos.split(val_frac, seed) if train is None else demos.split_sizes(train, val, seed)
    return Part(parts.train), Part(parts.val)


@struct.dataclass
class Demonstrations:
    """Expert transitions; every field has leading dim `N` (transitions).

    Attributes:
      obs: what the imitator sees, `[N, *obs_shape]` float32 (states) or uint8 (images).
      action: the clean expert action, the label, `[N, A] float32`.
      executed: the action actually executed, `[N, A] float32`; differs from
        `action` only where noise was injected.
      episode: episode id, `[N] int32`.
      t: time index within the episode, `[N] int32`.
      done: 1 where the step ended the episode by termination, `[N] float32`.
      reward: reward of the step, `[N] float32`.
      sim: simulator state before the step (`env.sim_state`), a dict of `[N, ...]` arrays.
    """

    obs: Any
    action: Any
    executed: Any
    episode: Any
    t: Any
    done: Any
    reward: Any
    sim: dict = struct.field(default_factory=dict)

    def __len__(self) -> int:
        return int(np.shape(self.action)[0])

    @property
    def episode_ids(self) -> np.ndarray:
        """Distinct episode ids, `[E] int32`, in order of appearance."""
        ids = np.asarray(self.episode)
        return ids[np.r_[True, ids[1:] != ids[:-1]]] if len(ids) else ids

    @property
    def num_episodes(self) -> int:
        return int(len(self.episode_ids))

    def take(self, idx) -> Demonstrations:
        """Rows `idx` (any NumPy index) of every field."""
        return jax.tree.map(lambda x: x[idx], self)

    def select_episodes(self, ids) -> Demonstrations:
        """The transitions of episodes `ids`, in their original order."""
        return self.take(np.flatnonzero(np.isin(np.asarray(self.episode), np.asarray(ids))))

    def split(self, val_frac: float = 0.2, seed: int = 0) -> Split:
        """`Split(train, val)`, split by whole episodes.

        `round(val_frac * E)` randomly chosen episodes (at least one, and at
        least one left for training when `E >= 2`) form the validation set, so
        no episode contributes to both.
        """
        if not 0.0 <= val_frac < 1.0:
            raise ValueError(f"val_frac must be in [0, 1), got {val_frac}")
        ids = self.episode_ids
        n_val = int(round(val_frac * len(ids)))
        if val_frac > 0 and len(ids) >= 2:
            n_val = min(max(n_val, 1), len(ids) - 1)
        val_ids = np.random.default_rng(seed).permutation(ids)[:n_val]
        is_val = np.isin(np.asarray(self.episode), val_ids)
        return Split(self.take(np.flatnonzero(~is_val)), self.take(np.flatnonzero(is_val)))

    def split_sizes(self, train: int, val: int, seed: int = 0) -> Split:
        """`Split(train, val)` of exactly `train` and `val` transitions, no episode in both.

        Episodes in a random order fill the validation split until it holds
        `val` transitions, the rest (in order) the training split; each is then
        cut to its size, keeping the first steps of the episode it cuts.

        Raises:
          ValueError: fewer than `train + val` transitions, or an episode
            structure that cannot give both sizes.
        """
        ids = self.episode_ids
        if len(self) < train + val:
            raise ValueError(f"{len(self):,} transitions in {len(ids)} episodes, fewer than the {train:,} + "
                             f"{val:,} the split needs; collect more episodes")
        episode = np.asarray(self.episode)
        sizes = {int(e): int(np.sum(episode == e)) for e in ids}
        val_ids, held = [], 0
        for e in np.random.default_rng(seed).permutation(ids):
            if held >= val:
                break
            val_ids.append(int(e))
            held += sizes[int(e)]
        rest = [int(e) for e in ids if int(e) not in val_ids]
        if sum(sizes[e] for e in rest) < train:
            raise ValueError(f"the validation split's {len(val_ids)} whole episodes leave "
                             f"{sum(sizes[e] for e in rest):,} transitions, fewer than {train:,} for training; "
                             "collect more episodes")

        def rows(episodes, n):
            idx = np.concatenate([np.flatnonzero(episode == e) for e in episodes])
            return idx[:n]

        return Split(self.take(rows(rest, train)), self.take(rows(val_ids, val)))


# -- files ----------------------------------------------------------------------------------

def _flat(demos: Demonstrations) -> dict[str, np.ndarray]:
    arrays = {k: np.asarray(getattr(demos, k)) for k in (*REQUIRED, "executed")}
    arrays.update({f"sim/{k}": np.asarray(v) for k, v in demos.sim.items()})
    return arrays


def _sha256(path: pathlib.Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def write_atomic(path: pathlib.Path, write) -> None:
    """`write(f)` into a temporary file of this process, then renamed to `path`.

    Readers never see a partial file, and two processes writing the same file
    (two sweeps collecting one dataset at once) do not mix their bytes.
    """
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def meta_path(path: pathlib.Path) -> pathlib.Path:
    return pathlib.Path(path).with_suffix(".json")


def save(path: str | os.PathLike, demos: Demonstrations, meta: dict | None = None) -> dict:
    """Writes `demos` to `path` (`.npz`) and its metadata beside it (`.json`).

    Returns:
      The metadata written: `meta` plus format, counts, shapes and checksum.
    """
    path = pathlib.Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"dataset files end in .npz, got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    meta_path(path).unlink(missing_ok=True)  # the old metadata must not vouch for new arrays
    write_atomic(path, lambda f: np.savez_compressed(f, **_flat(demos)))
    obs = np.asarray(demos.obs)
    full = {
        **(meta or {}),
        "format": FORMAT,
        "num_transitions": len(demos),
        "num_episodes": demos.num_episodes,
        "obs_shape": list(obs.shape[1:]),
        "obs_dtype": str(obs.dtype),
        "action_size": int(np.shape(demos.action)[1]),
        "sim_keys": sorted(demos.sim),
        "sha256": _sha256(path),
    }
    write_atomic(meta_path(path), lambda f: f.write((json.dumps(full, indent=2, sort_keys=True) + "\n").encode()))
    return full


def load(path: str | os.PathLike) -> tuple[Demonstrations, dict]:
    """Reads and validates a dataset written by `save` (or by hand in the same format).

    Returns:
      (demos, meta), arrays as NumPy.

    Raises:
      DataError: naming the file and what is wrong with it.
    """
    path = pathlib.Path(path)
    mpath = meta_path(path)
    if path.is_dir():
        raise DataError(f"{path} is a folder, not a dataset file")
    if not path.is_file():
        raise DataError(f"{path}: no such dataset file")
    if not mpath.is_file():
        try:  # an .npz is a zip archive: one that does not read is corrupt, whatever else is missing
            with zipfile.ZipFile(path) as z:
                damaged = z.testzip()
        except (zipfile.BadZipFile, EOFError, OSError, ValueError) as e:
            raise DataError(f"{path}: corrupt: not a readable .npz archive ({type(e).__name__}: {e})") from e
        if damaged is not None:
            raise DataError(f"{path}: corrupt: its member {damaged} fails its checksum")
        raise DataError(f"{path}: its metadata {mpath.name} is missing (an interrupted write?)")
    try:
        meta = json.loads(mpath.read_text())
        if not isinstance(meta, dict):
            raise ValueError("not a JSON object")
    except ValueError as e:
        raise DataError(f"{mpath}: unreadable metadata: {e}") from e
    _check_meta(meta, mpath)
    if "sha256" in meta and _sha256(path) != meta["sha256"]:
        raise DataError(f"{path}: contents differ from when it was written (SHA-256 mismatch); "
                        "the file is truncated or corrupt")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as e:
        raise DataError(f"{path}: truncated or unreadable ({type(e).__name__}: {e})") from e
    demos = from_arrays(arrays, where=str(path), meta=meta)
    return demos, meta


def _check_meta(meta: dict, where: pathlib.Path) -> None:
    """Refuses metadata fields that `load` relies on but that have the wrong type."""
    def is_int(v):
        return isinstance(v, int) and not isinstance(v, bool)

    wrong = [(k, want) for k, want, ok in (
        ("sha256", "a hex string", lambda v: isinstance(v, str)),
        ("obs", "a string", lambda v: isinstance(v, str)),
        ("obs_shape", "a list of ints", lambda v: isinstance(v, list) and all(is_int(d) and d >= 1 for d in v)),
        ("action_size", "an int >= 1", lambda v: is_int(v) and v >= 1),
    ) if k in meta and not ok(meta[k])]
    if wrong:
        k, want = wrong[0]
        raise DataError(f"{where}: metadata field '{k}' must be {want}, got {meta[k]!r}")


def _is_real(dtype: np.dtype) -> bool:
    """Bool, integer or floating (not complex, string or object)."""
    return dtype == np.bool_ or np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)


def from_arrays(arrays: dict[str, np.ndarray], where: str = "<arrays>", meta: dict | None = None) -> Demonstrations:
    """Builds `Demonstrations` from flat arrays (as in the `.npz`), validating them; see `load`."""
    meta = meta or {}
    missing = [k for k in REQUIRED if k not in arrays]
    if missing:
        raise DataError(f"{where}: missing keys {missing} (has {sorted(arrays)})")
    n = len(arrays["action"]) if np.ndim(arrays["action"]) else -1
    for k, v in arrays.items():
        if np.ndim(v) == 0 or len(v) != n:
            raise DataError(f"{where}: '{k}' has {np.shape(v)[:1] or 'no'} rows but 'action' has {n}: "
                            "mismatched lengths")
    if n == 0:
        raise DataError(f"{where}: no transitions")
    action = arrays["action"]
    if action.ndim != 2 or action.shape[1] < 1 or not np.issubdtype(action.dtype, np.floating):
        raise DataError(f"{where}: 'action' must be a [N, A] float array with A >= 1, got "
                        f"{action.dtype}{list(action.shape)}")
    executed = arrays.get("executed", action)
    if executed.shape != action.shape or not np.issubdtype(executed.dtype, np.floating):
        raise DataError(f"{where}: 'executed' must be a float array shaped like 'action' {list(action.shape)}, "
                        f"got {executed.dtype}{list(executed.shape)}")
    for k in ("episode", "t", "done", "reward"):
        if arrays[k].ndim != 1:
            raise DataError(f"{where}: '{k}' must be [N], got shape {list(arrays[k].shape)}")
    for k in ("episode", "t"):
        if not np.issubdtype(arrays[k].dtype, np.integer):
            raise DataError(f"{where}: '{k}' must be integers, got {arrays[k].dtype}")
    for k in ("done", "reward", *(k for k in arrays if k.startswith("sim/"))):
        if not _is_real(arrays[k].dtype):
            raise DataError(f"{where}: '{k}' must be numbers (bool, int or float), got {arrays[k].dtype}")
    obs = arrays["obs"]
    if obs.dtype != np.uint8 and not np.issubdtype(obs.dtype, np.floating):
        raise DataError(f"{where}: 'obs' must be uint8 (images) or float, got {obs.dtype}")
    if obs.ndim < 2:
        raise DataError(f"{where}: 'obs' must be [N, *obs_shape] (a vector or image per row), got shape "
                        f"{list(obs.shape)}")
    if "obs_shape" in meta and list(obs.shape[1:]) != list(meta["obs_shape"]):
        raise DataError(f"{where}: 'obs' rows have shape {list(obs.shape[1:])}, the metadata says {meta['obs_shape']}")
    if meta.get("obs") == "image" and obs.dtype != np.uint8:
        raise DataError(f"{where}: image observations must be uint8, got {obs.dtype}")
    if "action_size" in meta and action.shape[1] != meta["action_size"]:
        raise DataError(f"{where}: actions have {action.shape[1]} dims, the metadata says {meta['action_size']}")
    for k, v in arrays.items():
        if np.issubdtype(v.dtype, np.floating) and not np.all(np.isfinite(v)):
            bad = np.flatnonzero(~np.all(np.isfinite(v.reshape(n, -1)), axis=1))
            raise DataError(f"{where}: '{k}' has non-finite values in {len(bad)} rows (first: {bad[0]})")
    _check_episodes(arrays["episode"], arrays["t"], where)
    return Demonstrations(
        obs=obs, action=action.astype(np.float32), executed=executed.astype(np.float32),
        episode=arrays["episode"].astype(np.int32), t=arrays["t"].astype(np.int32),
        done=arrays["done"].astype(np.float32), reward=arrays["reward"].astype(np.float32),
        sim={k[4:]: v for k, v in arrays.items() if k.startswith("sim/")})


def _check_episodes(episode: np.ndarray, t: np.ndarray, where: str) -> None:
    new = np.r_[True, episode[1:] != episode[:-1]]
    starts = episode[new]
    if len(np.unique(starts)) != len(starts):
        raise DataError(f"{where}: an episode's rows are not contiguous (episode ids repeat after others)")
    expected = np.arange(len(t)) - np.maximum.accumulate(np.where(new, np.arange(len(t)), 0))
    bad = np.flatnonzero(t != expected)
    if len(bad):
        raise DataError(f"{where}: time index breaks at row {bad[0]} (t={t[bad[0]]}, expected {expected[bad[0]]}); "
                        "each episode must count t = 0, 1, 2, ...")


# -- cache ----------------------------------------------------------------------------------

def cache_path(data_dir: str | os.PathLike, settings: dict) -> pathlib.Path:
    """Where the dataset of collection `settings` lives: `DIR/<env>-<obs>-<hash>.npz`.

    The hash covers every setting (canonical JSON), so changing any of them,
    including the expert, names another file.
    """
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
    return pathlib.Path(data_dir) / f"{settings['env']}-{settings['obs']}-{digest}.npz"
