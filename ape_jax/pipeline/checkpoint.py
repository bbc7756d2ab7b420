"""A sweep's checkpoints and saved policies: every file a sweep writes but its results.json.

Resuming after any interruption, bit-exact:

Everything lives in `OUT/checkpoints/` (`rundir.RunDir.checkpoints`):

- `sweep.json`: the sweep's *fingerprint* (environment, observations, every
  preset setting, methods, data). A directory whose fingerprint differs, or
  that has none, is refused with a `CheckpointError`, never overwritten.
- `ape.npz`, `eval-<group>.npz` (`eval-<group>-at<I>.npz`; `<group>`: `h<H>`, or
  `full-h1` for `bc-full`'s): the outputs of finished phases (the APE fit; each
  evaluation group, at the end and at each iteration `I` of `Budget.eval_at`),
  written to a temporary name and renamed.
- `train-<program>-at<I>.npz`: a program's policies at iteration `I` of
  `Budget.eval_at`, written when training passes it.
- `train-<program>/<step>/`: the training state of one compiled program (every
  configuration × seed, vmapped) and its loss curves so far, saved with orbax's
  `CheckpointManager` every `every` iterations and when the program finishes.
  orbax writes each step to a temporary directory and renames it when complete,
  so a kill mid-save leaves the previous step intact.

Training runs in fixed chunks and the state holds every random key, so
continuing from a saved state runs the same compiled chunks on the same inputs
as an uninterrupted run: on one machine the results are bit-identical.

The finished sweep's policies go to `OUT/params/` (`RunDir.params`; `save_policies`,
`load_policies`): per group of one observation and history, `h<H>/` (the sweep's
observation) or `<observation>-h<H>/` (e.g. `full-h1/`, `bc-full`'s), orbax: the
parameters, leaves `[len(runs), ...]`, and the observation statistics; beside it
`<group>.json`: `{"history", "observation", "runs"}` (the runs in order), which
`experiments.evaluate` evaluates again. A method whose module reads its policies itself
(`ape_jax.evaluate.Runtime`) saves them in groups of their own, `h<H>-<program>/`
(e.g. `h1-action-chunks/`), read back through its runtime. Files written before groups had an
observation hold the runs' list alone, named `h<H>.json`: the sweep's observation,
history `H`.

While a sweep runs it holds `OUT/sweep.lock` (`OutLock`): a second sweep into the
same folder is refused at its start, naming the holder, instead of colliding at its
first checkpoint. The lock is the kernel's (`flock`), so a killed sweep leaves no
stale lock: the file it leaves names a holder that no longer holds it.
"""

from __future__ import annotations

import datetime
import fcntl
import json
import os
import pathlib
import re
import shutil
import socket
import sys
import time
from typing import Any

import numpy as np

from ape_jax.pipeline.data import write_atomic
from ape_jax.pipeline.rundir import RunDir

FINGERPRINT = "sweep.json"
_GROUP_FIELDS = ("runs", "history", "observation")  # a policy group's record in `<name>.json`, not in orbax


class CheckpointError(ValueError):
    """A checkpoint directory that cannot be resumed: foreign, of another sweep, or unreadable."""


LOCK = RunDir.LOCK


class LockHeld(CheckpointError):
    """The output folder is held by another running sweep (one line naming it)."""


class OutLock:
    """A sweep's hold on its output folder: `OUT/sweep.lock`, locked with `flock` while the sweep runs.

    `acquire` creates the folder if needed and takes the lock, or raises `LockHeld` naming the holder (pid, host,
    start time, from the file) when another process has it. The kernel drops the lock when its process ends,
    however it ends, so the file a killed sweep leaves is simply taken over. `release` deletes the file, then
    unlocks; a process that opened the file before it was deleted finds, after locking, that the path no longer
    names the file it locked, and opens it again. `release(restore=True)` (a sweep that refused, having done
    nothing) leaves the folder as it was found instead: a file it took over gets its old contents back.
    `took_over` then names the sweep whose stale file was taken over (`pid P on HOST, started T`), else None.
    """

    def __init__(self, out: os.PathLike):
        self.path = RunDir(out).lock
        self._fd: int | None = None
        self._found: bytes | None = None   # the contents of a file that was there before `acquire`
        self.took_over: str | None = None

    def acquire(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        while True:
            try:
                fd, found = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644), None
            except FileExistsError:
                try:
                    fd = os.open(self.path, os.O_RDWR)
                except FileNotFoundError:  # deleted by its holder's release since: create it
                    continue
                found = os.pread(fd, 1 << 16, 0)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(fd)
                os.close(fd)
                raise LockHeld(f"{self.path.parent} is in use by another sweep ({holder}); wait for it to finish, or "
                               "use another --out") from None
            except OSError:  # a file system without locks (ENOLCK): the sweep runs unguarded, as before the lock
                break
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # released and deleted by its holder between our open and our lock: try the new file
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
                  "command": sys.argv}
        # a file left behind and not locked: its sweep ended without releasing it (killed: SIGKILL, a power cut)
        self.took_over = None if found is None else _recorded(found) or "a sweep that left no record"
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
        self._fd, self._found = fd, found

    def release(self, restore: bool = False) -> None:
        if self._fd is None:
            return
        try:
            if restore and self._found is not None:
                os.ftruncate(self._fd, 0)
                os.pwrite(self._fd, self._found, 0)
            else:
                self.path.unlink(missing_ok=True)
        finally:
            os.close(self._fd)  # closing drops the lock
            self._fd = None

    def __enter__(self) -> OutLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _holder(fd: int) -> str:
    """Who holds the lock, as its file records it (`pid P on HOST, started T`)."""
    try:
        return _recorded(os.pread(fd, 1 << 16, 0)) or "its lock file is still being written"
    except OSError:
        return "its lock file is still being written"


def _recorded(text: bytes) -> str | None:
    """The sweep a lock file's contents name, `pid P on HOST, started T`; None where they name none."""
    try:
        record = json.loads(text.decode())
        return f"pid {int(record['pid'])} on {record['host']}, started {record['started']}"
    except (ValueError, KeyError, TypeError):
        return None


def _differences(old: Any, new: Any, prefix: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new), key=str):
            out += _differences(old.get(k), new.get(k), f"{prefix}{k}.")
        return out
    return [] if old == new else [f"{prefix.rstrip('.')} ({old!r} there, {new!r} now)"]


def differences(old: dict, new: dict) -> list[str]:
    """The settings in which two fingerprints differ, as readable strings. A settings field a fingerprint
    predates (a recipe field added later, say) counts as its default, which is what that sweep ran with."""
    return _differences(*(_with_defaults(json.loads(json.dumps(f))) for f in (old, new)))


def _with_defaults(fingerprint: Any) -> Any:
    # here, not at the top: the settings import JAX and Flax, which reading a checkpoint's arrays does not need
    from ape_jax.pipeline.presets import Settings, SettingsError

    if isinstance(fingerprint, dict) and isinstance(fingerprint.get("settings"), dict):
        try:
            settings = Settings.from_json(fingerprint["settings"]).to_json()
        except (SettingsError, TypeError, ValueError):  # not this code's settings: compared as they are
            return fingerprint
        settings["protocol"].pop("doc", None)   # the protocol's description, not a setting
        return {**current_names(fingerprint), "settings": json.loads(json.dumps(settings))}
    return fingerprint


def current_names(fingerprint: dict) -> dict:
    """A fingerprint with the protocol and the expert called by their names now (`tasks.FORMER_PROTOCOLS`,
    `FORMER_EXPERTS`), in its `protocol` block and in its data key's expert description: a sweep started before
    the renaming resumes under the new names."""
    from ape_jax import tasks

    out = json.loads(json.dumps(fingerprint))
    if isinstance(out.get("protocol"), dict):
        out["protocol"] = tasks.current_names(out["protocol"])
    if isinstance(out.get("data"), dict) and isinstance(out["data"].get("expert"), dict):
        out["data"]["expert"] = tasks.current_expert(out["data"]["expert"])
    return out


class SweepCheckpoint:
    """The checkpoints of one sweep in `directory` (see the module docstring).

    Args:
      directory: `OUT/checkpoints`.
      fingerprint: JSON-able settings that identify the sweep.
      every: save training states every this many iterations (rounded up to
        whole chunks) and at the end of each program.
    """

    def __init__(self, directory: os.PathLike, fingerprint: dict, every: int):
        if every < 1:
            raise ValueError(f"checkpoint interval must be >= 1 iteration, got {every}")
        self.directory = pathlib.Path(directory)
        self.fingerprint = json.loads(json.dumps(fingerprint))
        self.every = every
        self.resumed = False  # set by `open`
        self.save_s = 0.0     # seconds spent saving, phase outputs and training states

    def open(self) -> bool:
        """Validates an existing directory or creates a new one; True (and `resumed`) when there is something to
        resume."""
        path = self.directory / FINGERPRINT
        if self.directory.exists():
            try:
                old = json.loads(path.read_text())
                if not isinstance(old, dict):
                    raise ValueError("not a JSON object")
            except (OSError, ValueError) as e:
                raise CheckpointError(
                    f"{self.directory} is not a checkpoint of this project's sweep ({path.name}: "
                    f"{e.strerror if isinstance(e, OSError) else e}); move it away, or pass --fresh to delete it"
                ) from e
            diff = differences(old, self.fingerprint)
            if diff:
                raise CheckpointError(f"{self.directory} holds a checkpoint of a different sweep, differing in "
                                      f"{'; '.join(diff[:4])}{' …' if len(diff) > 4 else ''}; use another --out, "
                                      "or pass --fresh to delete it")
            self.resumed = any(p.name != FINGERPRINT for p in self.directory.iterdir())
            return self.resumed
        self.directory.mkdir(parents=True)
        write_atomic(path, lambda f: f.write((json.dumps(self.fingerprint, indent=2) + "\n").encode()))
        return False

    def discard_if_empty(self) -> None:
        """Deletes the directory if it holds nothing but the fingerprint (a sweep refused before any work)."""
        if self.directory.is_dir() and all(p.name == FINGERPRINT for p in self.directory.iterdir()):
            self.clear()

    def clear(self) -> None:
        """Deletes the checkpoints (after the sweep's outputs are written)."""
        shutil.rmtree(self.directory, ignore_errors=True)

    # Phase outputs: flat dicts of numpy arrays.
    def save_arrays(self, name: str, arrays: dict[str, Any]) -> None:
        t0 = time.perf_counter()
        write_atomic(self.directory / f"{name}.npz",
                     lambda f: np.savez(f, **{k: np.asarray(v) for k, v in arrays.items()}))
        self.save_s += time.perf_counter() - t0

    def load_arrays(self, name: str) -> dict[str, np.ndarray] | None:
        """The arrays saved under `name`, or None if that phase has not finished."""
        path = self.directory / f"{name}.npz"
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as f:
                return {k: f[k] for k in f.files}
        except Exception as e:  # noqa: BLE001 - any failure to read is a corrupt file
            raise CheckpointError(f"{path} is unreadable ({type(e).__name__}: {e}); delete it to redo that "
                                  "phase, or pass --fresh to start over") from e

    def program(self, name: str) -> ProgramCheckpoint:
        return ProgramCheckpoint(self.directory / f"train-{name}", self.every, self)


class ProgramCheckpoint:
    """The training state and loss curves of one compiled program, by iteration (orbax `CheckpointManager`)."""

    def __init__(self, directory: pathlib.Path, every: int, owner: SweepCheckpoint | None = None):
        self.directory, self.every, self.owner = directory, every, owner
        self._last_saved = 0

    def _manager(self):
        import orbax.checkpoint as ocp

        alone = _alone()
        if alone:  # orbax cannot create the directory for a subset of the processes
            self.directory.mkdir(parents=True, exist_ok=True)
        options = ocp.CheckpointManagerOptions(max_to_keep=1, enable_async_checkpointing=False, create=not alone,
                                               **alone)
        return ocp.CheckpointManager(self.directory.absolute(), options=options)

    def restore(self, target: Any) -> tuple[int, Any, dict] | None:
        """`(iteration, state, curves)` of the latest save, state laid out like `target`; None if none."""
        import orbax.checkpoint as ocp

        if not self.directory.exists():
            return None
        try:
            with self._manager() as manager:
                step = manager.latest_step()
                if step is None:
                    return None
                out = manager.restore(step, args=ocp.args.Composite(state=ocp.args.StandardRestore(target),
                                                                    curves=ocp.args.StandardRestore()))
        except Exception as e:  # noqa: BLE001 - orbax raises many types for damaged files
            raise CheckpointError(f"{self.directory} is unreadable or not this sweep's training state "
                                  f"({type(e).__name__}: {str(e).splitlines()[0][:200]}); delete it to retrain "
                                  "that program, or pass --fresh to start over") from e
        self._last_saved = step
        return step, out["state"], {k: np.asarray(v) for k, v in out["curves"].items()}

    def due(self, iteration: int) -> bool:
        """Whether a save is due after `iteration` (a multiple of `every` has been passed since the last)."""
        return iteration // self.every > self._last_saved // self.every

    def _snapshot_name(self, iteration: int) -> str:
        return f"{self.directory.name}-at{iteration}"

    def save_snapshot(self, iteration: int, params: Any) -> None:
        """Saves the policies at `iteration` (`Budget.eval_at`), as `<program>-at<iteration>.npz` beside the
        training states: written when taken, so a state saved later never lacks the snapshots before it."""
        import jax

        if self.owner is not None:
            leaves = jax.tree.leaves(jax.device_get(params))
            self.owner.save_arrays(self._snapshot_name(iteration), {str(i): x for i, x in enumerate(leaves)})

    def load_snapshot(self, iteration: int, like: Any) -> Any:
        """The policies saved at `iteration`, laid out like `like`; a `CheckpointError` if they are missing."""
        import jax

        saved = self.owner.load_arrays(self._snapshot_name(iteration)) if self.owner is not None else None
        leaves, treedef = jax.tree.flatten(like)
        if saved is None or len(saved) != len(leaves):
            raise CheckpointError(f"{self.directory} resumes past iteration {iteration} but the policies saved "
                                  f"there ({self._snapshot_name(iteration)}.npz) are missing or not this "
                                  "program's; pass --fresh to start over")
        return jax.tree.unflatten(treedef, [saved[str(i)] for i in range(len(leaves))])

    def save(self, iteration: int, state: Any, curves: dict[str, np.ndarray]) -> None:
        import orbax.checkpoint as ocp

        t0 = time.perf_counter()
        with self._manager() as manager:
            manager.save(iteration, args=ocp.args.Composite(state=ocp.args.StandardSave(state),
                                                            curves=ocp.args.StandardSave(curves)), force=True)
        self._last_saved = iteration
        if self.owner is not None:
            self.owner.save_s += time.perf_counter() - t0


def _alone() -> dict:
    """orbax's options for a process that saves alone: `{}` in a one-process run.

    In a run of several JAX processes (`jax.distributed`) orbax waits at
    barriers for all of them at every save, but only process 0 writes here:
    the others never call in, and would never arrive.
    """
    import jax

    if jax.process_count() == 1:
        return {}
    import orbax.checkpoint as ocp

    me = jax.process_index()
    return {"multiprocessing_options": ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me})}


# -- phase outputs with structure: the APE fit -----------------------------------------------------------------------

def save_ape(checkpoint: SweepCheckpoint | None, fit: Any) -> None:
    """Saves an `ApeFit` (ψ flax-serialised) as the `ape` phase; nothing without a checkpoint."""
    import flax.serialization

    if checkpoint is None:
        return
    checkpoint.save_arrays("ape", {"train": fit.train, "val": fit.val, "scale": fit.scale,
                                   "final_fit_mse": fit.final_fit_mse,
                                   "psi": np.frombuffer(flax.serialization.to_bytes(fit.params), np.uint8)})


def load_ape(checkpoint: SweepCheckpoint | None, make: Any) -> Any:
    """The saved `ape` phase as `make(params=, train=, val=, scale=, final_fit_mse=)`, or None."""
    import flax.serialization

    saved = checkpoint.load_arrays("ape") if checkpoint is not None else None
    if saved is None:
        return None
    return make(params=flax.serialization.msgpack_restore(saved["psi"].tobytes()), train=saved["train"],
                val=saved["val"], scale=float(saved["scale"]), final_fit_mse=float(saved["final_fit_mse"]))


def save_evaluation(checkpoint: SweepCheckpoint | None, name: str, out: dict, losses: dict) -> None:
    """Saves one evaluation group's outputs (`eval/<k>`, `<split>/<k>` arrays)."""
    if checkpoint is not None:
        checkpoint.save_arrays(name, {**{f"eval/{k}": v for k, v in out.items()},
                                      **{f"{s}/{k}": v for s, ls in losses.items() for k, v in ls.items()}})


def load_evaluation(checkpoint: SweepCheckpoint | None, name: str) -> tuple[dict, dict] | None:
    """`(eval outputs, {"train": losses, "val": losses})` of a saved evaluation group, or None."""
    saved = checkpoint.load_arrays(name) if checkpoint is not None else None
    if saved is None:
        return None
    parts: dict[str, dict] = {"eval": {}, "train": {}, "val": {}}
    for k, v in saved.items():
        part, key = k.split("/", 1)
        parts[part][key] = v
    return parts["eval"], {"train": parts["train"], "val": parts["val"]}


# -- a finished sweep's policies -------------------------------------------------------------------------------------

class PolicyError(ValueError):
    """Saved policies that are missing or unreadable (one line)."""


# `sweep.PolicyGroup.name`: `h<H>`, `<observation>-h<H>`, and either with `-<kind>` (a method's own policies)
GROUP_NAME = re.compile(r"^(?:(?P<observation>[a-z]+)-)?h(?P<history>[0-9]+)(?:-(?P<kind>[a-z0-9][a-z0-9_.-]*))?$")


def save_policies(params_dir: os.PathLike, groups: dict[str, dict]) -> None:
    """Writes `{name: {"runs": [...], "params": ..., "obs_mean", "obs_std", "history", "observation"}}` under
    `params_dir` (names `sweep.PolicyGroup.name`: `h<H>`, `full-h1`).

    Each group's orbax folder is replaced whole; `<name>.json` (the group's history and observation, and its
    runs) is written atomically after it (the runs' list alone for a block that gives no history).
    """
    import jax
    import orbax.checkpoint as ocp

    params_dir = pathlib.Path(params_dir)
    # orbax saves to a temporary name and renames when done: create the parent first.
    params_dir.mkdir(parents=True, exist_ok=True)
    with ocp.StandardCheckpointer(**_alone()) as ckpt:
        for name, block in groups.items():
            target = (params_dir / name).absolute()
            if target.exists():
                shutil.rmtree(target)
            tree = {k: v for k, v in block.items() if k not in _GROUP_FIELDS and v is not None}
            ckpt.save(target, jax.tree.map(np.asarray, tree))
            record = ({"history": int(block["history"]), "observation": block.get("observation"),
                       "runs": block["runs"]} if "history" in block else block["runs"])
            write_atomic(params_dir / f"{name}.json",
                         lambda f, record=record: f.write((json.dumps(record, indent=2) + "\n").encode()))


def load_policies(params_dir: os.PathLike) -> dict[str, dict]:
    """What `save_policies` wrote, per group: `runs`, `params` (leaves `[len(runs), ...]`), `obs_mean`/`obs_std`
    (None for images), `history` and `observation` (None: the sweep's own; files that record neither are
    `h<H>`, the sweep's observation at history `H`)."""
    import orbax.checkpoint as ocp

    params_dir = pathlib.Path(params_dir)
    groups = sorted(p.stem for p in params_dir.glob("*.json") if GROUP_NAME.match(p.stem))
    if not groups:
        raise PolicyError(f"{params_dir} holds no saved policies (h*.json beside orbax folders)")
    out = {}
    with ocp.StandardCheckpointer() as ckpt:
        for name in groups:
            if not (params_dir / name).is_dir():
                raise PolicyError(f"{params_dir / name} is missing: the sweep's parameters were not saved")
            try:
                tree = ckpt.restore((params_dir / name).absolute())
                record = json.loads((params_dir / f"{name}.json").read_text())
            except Exception as e:  # noqa: BLE001 - orbax raises many types for damaged files
                raise PolicyError(f"{params_dir / name} is unreadable ({type(e).__name__}: "
                                  f"{str(e).splitlines()[0][:200] if str(e) else ''})") from e
            if isinstance(record, list):  # written before groups recorded their observation: `h<H>`
                match = GROUP_NAME.match(name)
                record = {"history": int(match["history"]), "observation": match["observation"], "runs": record}
            out[name] = {"runs": record["runs"], "params": tree["params"], "obs_mean": tree.get("obs_mean"),
                         "obs_std": tree.get("obs_std"), "history": int(record["history"]),
                         "observation": record.get("observation")}
    return out
