"""The perception encoder trained on with the policy (`recipe.perception_training=finetune`): the paper's setting,
where a pretrained network starts the policy's encoder and every weight learns from the BC loss.

    PretrainedEncoder(sha256)(frames)   # [..., h, w, 3·F] frames in [0, 1] -> [..., F·E] the frames' embeddings

Its parameters start as the encoder file's (`perceived.loaded`: the file this process resolved for the recipe),
and from there they are the policy's own: the same optimiser, learning rate and loss train them with the head.
Each of the `F` frames a policy sees goes through the one encoder, as the frozen stage embeds each frame alone
(`perceived.Perceived`), so at the first update the policy sees what the frozen one sees (bar the frozen stage's
standardisation of the embeddings with the training rows' statistics, which a trainable encoder has no fixed
statistics for). The read-out layer is carried along untrained (nothing reads it).
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from ape_jax.perception.perceived import loaded


class PretrainedEncoder(nn.Module):
    """`[..., h, w, 3·F]` stacked frames in [0, 1] -> `[..., F·E]`: each frame's embedding through the encoder of
    SHA-256 `sha256`, its weights a parameter (`net`) initialised from the file."""

    sha256: str

    @nn.compact
    def __call__(self, frames: jax.Array) -> jax.Array:
        encoder = loaded(self.sha256)
        weights = self.param("net", lambda _key: jax.tree.map(jnp.asarray, encoder.params["params"]))
        *lead, h, w, c = frames.shape
        per_frame = jnp.moveaxis(frames.reshape(*lead, h, w, c // 3, 3), -2, -4)   # [..., F, h, w, 3]
        # the network reads uint8 values (it divides by 255): the policy's [0, 1] frames scaled back
        _, embedding = encoder.net.apply({"params": weights}, per_frame * 255.0, return_embedding=True)
        return embedding.reshape(*lead, -1)
