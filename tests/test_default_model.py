"""The shipped default model: present, under the size budget, and it loads as the tiny preset."""

from solaris_env.dream_env import DEFAULT_CHECKPOINT
from solaris_env.world_model.world_model import WorldModel


def test_shipped_default_model_loads_and_is_small():
    size = sum(f.stat().st_size for f in DEFAULT_CHECKPOINT.iterdir())
    assert size < 50 * 2**20, f"{DEFAULT_CHECKPOINT} is {size / 2**20:.1f} MiB (budget 50)"
    for name in ("training_log.md", "eval.json", "train_config.json", "contact_sheet.png"):
        assert (DEFAULT_CHECKPOINT / name).is_file(), name
    model = WorldModel.load(DEFAULT_CHECKPOINT)
    assert model.config.name == "tiny" and model.num_players == 2 and model.frame_shape == (64, 64, 3)
