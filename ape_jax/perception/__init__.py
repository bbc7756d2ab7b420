"""Perceive, then imitate: a perception encoder pretrained once on a task's frames and shared by every method.

The paper's camera policies start from an ImageNet-pretrained ResNet; this suite cannot download one and learns too
little perception from 100 demonstrations on a CPU. So a task may declare a perception card (`ape_jax.tasks.
Perception`): an encoder trained on frames of its training layouts to read what one frame shows (its one-frame
state; MuJoCo's `pos`), never the expert's actions (`ape_jax.pipeline.perception.pretrain`, `python -m
experiments.perception`). It is shipped with its card (`card`: the file format, the checks that refuse a wrong
file), and a camera sweep sees its frames through it with `--set recipe.perception=task` (or a path to a user's
encoder file): `perceived`. This package is the core's (network, file, environment); what needs collected
demonstrations or a sweep's settings is `ape_jax.pipeline.perception`'s.
"""

from ape_jax.perception.card import Encoder, PerceptionError, load, save  # noqa: F401
from ape_jax.perception.perceived import (NONE, OUTPUTS, TASK, Perceived, check_sweep, embed_frames,  # noqa: F401
                                          perceive, resolve, seeing, shipped_path)
