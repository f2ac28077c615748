"""The autoencoder capacity benchmark: candidate layouts, the surface of an episode, and one short end-to-end
run on real engine episodes (every candidate trains, is scored per surface, and the result is written)."""

import json

import numpy as np
import pytest

from benchmarks import autoencoder_capacity as AC


def test_candidates_have_the_layouts_they_are_named_after():
    for name in AC.CANDIDATES:
        cfg = AC.candidate_config(name)
        spatial = int(name[1])
        assert cfg.vae.spatial_factor == spatial and cfg.latent_height == 64 // spatial
        assert cfg.latent_channels == (32 if "_z32" in name else 16)
        assert cfg.frames_per_step == (2 if name.endswith("_k2") else 4)
        assert cfg.vae.latent_mean == ()  # trained from scratch: no statistics yet
    with pytest.raises(ValueError, match="candidate must be one of"):
        AC.candidate_config("s2_z8")


def test_surface_of_an_episode_follows_the_instance():
    assert [AC.surface_of({"world_type": "flat", "instance": i}) for i in range(6)] == [
        "grass", "grass", "snow", "sand", "red_sand", "grass"]
    assert AC.surface_of({"world_type": "normal", "instance": 3}) == "normal"


def test_sharpness_ratio_is_one_for_the_truth_and_zero_for_a_flat_frame():
    truth = np.random.default_rng(0).integers(0, 256, (2, 5, 16, 16, 3), dtype=np.uint8)
    assert AC.sharpness_ratio(truth, truth) == 1.0
    assert AC.sharpness_ratio(np.full_like(truth, 90), truth) == 0.0


def test_contact_sheet_stacks_truth_over_each_candidate():
    truth = np.zeros((2, 5, 8, 8, 3), np.uint8)
    rec = np.full((2, 5, 8, 8, 3), 200, np.uint8)
    sheet = AC.contact_sheet({"a": (truth, rec), "b": (truth, rec)})
    assert sheet.shape == (3 * 8, 2 * 8, 3) and sheet[:8].max() == 0 and sheet[8:].min() == 200


@pytest.mark.slow
def test_a_short_run_scores_each_candidate_per_surface(tmp_path):
    from solaris_env.engine import cli as engine_cli

    data = tmp_path / "data"
    assert engine_cli.main(["collect", "--out", str(data), "--resolution", "32", "--seed", "5", "--episodes", "4",
                            "--world", "flat", "--types", "walkLook", "--test-fraction", "0.25"]) == 0
    out = tmp_path / "ae.json"
    result = AC.main(["--data", str(data), "--candidates", "s8_z16", "s4_z16", "--steps", "1", "--batch-size", "1",
                      "--test-per-episode", "1", "--out", str(out)])
    saved = json.loads(out.read_text())
    assert saved["candidates"].keys() == result["candidates"].keys() == {"s8_z16", "s4_z16"}
    for row in saved["candidates"].values():
        assert row["updates"] == 1 and 0 < row["test_psnr_db"] < 60
        assert row["test_psnr_min_surface_db"] == min(row["test_psnr_by_surface_db"].values())
        assert 0 < row["test_sharpness_ratio"] and row["test_sharpness_ratio_by_surface"].keys() == \
            row["test_psnr_by_surface_db"].keys()
    assert out.with_suffix(".png").is_file()
