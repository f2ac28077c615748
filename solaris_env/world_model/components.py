"""The world model's three networks, by the names our checkpoints and the training code use for them
(docs/model.md §9.1: ``dit/...``, ``vae/...``, ``image_encoder/...``), built abstractly from a config."""

from __future__ import annotations

from flax import nnx

from solaris_env.world_model.config import WorldModelConfig
from solaris_env.world_model.dit import WorldDiT
from solaris_env.world_model.image_encoder import ImageEncoder
from solaris_env.world_model.vae import CausalVideoVAE

COMPONENTS = ("dit", "vae", "image_encoder")


def abstract_modules(config: WorldModelConfig) -> tuple:
    """(dit, vae, image_encoder) with abstract (shape-only) parameters: no compute, no memory."""
    return (nnx.eval_shape(lambda: WorldDiT(config, rngs=nnx.Rngs(0))),
            nnx.eval_shape(lambda: CausalVideoVAE(config.vae, rngs=nnx.Rngs(0))),
            nnx.eval_shape(lambda: ImageEncoder(config.image_encoder, rngs=nnx.Rngs(0))))
