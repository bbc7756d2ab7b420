"""A perception encoder's file: its parameters and its card, in one `.npz`, and the checks that refuse a wrong one.

The file (`save`, `load`; format 1) is a NumPy `.npz` archive:
  * `card.json`: a 0-d string array holding the card, a JSON object:
      - `format` (1), `task` (its `envs.make` name), `targets` (the one-frame targets' names, in order),
        `target_obs` (the observation mode they come from, e.g. `pos`), `image_size` `[H, W]`, `task_version`
        (null for a task without versions), `palette` (the colours of the frames it was trained on: ToyTown's
        `weather`; null for a task with one palette);
      - `net` (`net.net_spec`): the network's shape; `target_mean`, `target_std`: the targets' standardisation;
      - `data`, `training`: what it was trained on and how, and what it cost; `heldout`: per held-out condition,
        `{target: 1 − R²}` (`pretrain.scores`).
  * `params/<module>/<name>`: each parameter array, float32 (Flax's `{"params": {module: {name: array}}}`).
A user's own encoder (an ImageNet network converted to arrays) takes the same format; `docs/perception.md` shows
how. Its SHA-256 is the file's bytes', recorded in a sweep's settings (`recipe.perception_sha256`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import pathlib
import zipfile
from typing import Any

import numpy as np

from ape_jax.perception.net import PerceptionNet, net_of

FORMAT = 1
CARD = "card.json"
PARAMS = "params/"


class PerceptionError(ValueError):
    """An encoder that cannot be used here (one line, naming the file and what to do)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Encoder:
    """A loaded perception encoder: its network, parameters, card, and the file's SHA-256 and path."""

    net: PerceptionNet
    params: Any
    card: dict
    sha256: str
    path: str

    @property
    def embedding_size(self) -> int:
        return int(self.net.embedding)

    def describe(self) -> dict:
        """What results record of it: name, SHA-256, targets, embedding size, image size, held-out scores."""
        c = self.card
        return {"name": pathlib.Path(self.path).name, "sha256": self.sha256, "task": c["task"],
                "targets": list(c["targets"]), "embedding": self.embedding_size, "image_size": list(c["image_size"]),
                "task_version": c.get("task_version"), "palette": c.get("palette"),
                "heldout": c.get("heldout")}


def file_sha256(path: str | pathlib.Path) -> str:
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def save(path: str | pathlib.Path, params: Any, card: dict) -> str:
    """Writes `params` (Flax's nested dict) and `card` to `path` (the module docstring's format), atomically;
    returns the file's SHA-256."""
    flat = {}
    for module, leaves in params["params"].items():
        for name, value in leaves.items():
            flat[f"{PARAMS}{module}/{name}"] = np.asarray(value, np.float32)
    buffer = io.BytesIO()
    np.savez(buffer, **{CARD: np.array(json.dumps({"format": FORMAT, **card}, sort_keys=True))}, **flat)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(buffer.getvalue())
    tmp.replace(path)
    return hashlib.sha256(buffer.getvalue()).hexdigest()


def load(path: str | pathlib.Path, sha256: str | None = None) -> Encoder:
    """The encoder in `path`; `PerceptionError` (one line) for a missing, truncated or malformed file, or one whose
    SHA-256 is not `sha256` (when given)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise PerceptionError(f"{path}: no such encoder file")
    raw = path.read_bytes()
    digest = hashlib.sha256(raw).hexdigest()
    if sha256 is not None and digest != sha256:
        raise PerceptionError(f"{path}: SHA-256 {digest[:12]}… is not the {sha256[:12]}… asked for "
                              "(recipe.perception_sha256): another encoder, or the file changed")
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as z:
            card = json.loads(str(z[CARD][()]))
            params: dict = {}
            for key in z.files:
                if key.startswith(PARAMS):
                    module, name = key[len(PARAMS):].split("/")
                    params.setdefault(module, {})[name] = np.asarray(z[key], np.float32)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        raise PerceptionError(f"{path}: not a readable encoder file (truncated or not an ape_jax encoder: "
                              f"{type(e).__name__})") from None
    if not isinstance(card, dict) or card.get("format") != FORMAT:
        raise PerceptionError(f"{path}: encoder format {card.get('format') if isinstance(card, dict) else None!r}, "
                              f"this code reads format {FORMAT}")
    missing = [k for k in ("task", "targets", "image_size", "net", "target_mean", "target_std") if k not in card]
    if missing:
        raise PerceptionError(f"{path}: the encoder's card lacks {', '.join(missing)}")
    net = net_of({**card["net"], "targets": len(card["targets"])})
    expected = _shapes(net, tuple(card["image_size"]))
    have = {m: {n: v.shape for n, v in leaves.items()} for m, leaves in params.items()}
    if have != expected:
        raise PerceptionError(f"{path}: its parameters do not fit the network its card describes")
    return Encoder(net=net, params={"params": params}, card=card, sha256=digest, path=str(path))


def _shapes(net: PerceptionNet, image_size: tuple[int, int]) -> dict:
    import jax

    shapes = jax.eval_shape(lambda: net.init(jax.random.PRNGKey(0), np.zeros((1, *image_size, 3), np.uint8)))
    return {m: {n: tuple(v.shape) for n, v in leaves.items()} for m, leaves in shapes["params"].items()}


def check_fits(encoder: Encoder, task: str, image_size: tuple[int, int], task_version: int | None,
               palette: str | None) -> None:
    """`PerceptionError` (one line) where `encoder` was made for another task, image size, task version or
    palette than the sweep's (its demonstrations' frames: `palette` is the training palette)."""
    c, where = encoder.card, encoder.path
    if c["task"] != task:
        raise PerceptionError(f"{where}: an encoder of {c['task']}'s frames, not {task}'s")
    if tuple(c["image_size"]) != tuple(image_size):
        raise PerceptionError(f"{where}: made for {c['image_size'][0]}×{c['image_size'][1]} frames, not the sweep's "
                              f"{image_size[0]}×{image_size[1]} (--set protocol.image_size=...)")
    if c.get("task_version") != task_version:
        raise PerceptionError(f"{where}: made for task version {c.get('task_version')}, not the sweep's "
                              f"{task_version}: what the camera shows differs")
    if c.get("palette") != palette:
        raise PerceptionError(f"{where}: trained on the {c.get('palette')!r} palette, not the demonstrations' "
                              f"{palette!r}")
