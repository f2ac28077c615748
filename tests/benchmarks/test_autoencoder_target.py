"""benchmarks.autoencoder_target: PSNR per surface and the judges on reconstructions, checked on hand-made
reconstructions (a perfect one and a flat grey one) and end to end on a random test-preset model."""

import json

import numpy as np
import pytest

from benchmarks import autoencoder_target as AT
from benchmarks.eval_tasks import EVAL_NUM_FRAMES, make_segments
from solaris_env.judges.episodes import find_episodes
from solaris_env.judges.judge import Judge
from solaris_env.judges.scoring import judge_episodes

SIZE = 32  # the test preset's frames


def identity(obs_BTPHW3):
    return obs_BTPHW3.copy()


def flat_grey(obs_BTPHW3):
    return np.full_like(obs_BTPHW3, 128)


@pytest.fixture(scope="module")
def heldout(tmp_path_factory):
    from solaris_env.engine import cli

    root = tmp_path_factory.mktemp("heldout")
    assert cli.main(["collect", "--out", str(root), "--resolution", str(SIZE), "--seed", "5", "--episodes", "3",
                     "--world", "mixed", "--instances", "3", "--types", "walkLook", "--test-fraction", "1"]) == 0
    return root


@pytest.fixture(scope="module")
def eval_data(collect_eval):
    return collect_eval(("rotationEval", "oneLooksAwayEval"), SIZE, seed=3)


@pytest.fixture(scope="module")
def judge():
    return Judge.load()


@pytest.fixture(scope="module")
def segments(eval_data):
    segs, skipped = make_segments(find_episodes(eval_data), EVAL_NUM_FRAMES)
    assert segs and not skipped
    return segs


def test_heldout_windows_are_whole_latent_chunks_of_both_players(heldout):
    windows = AT.heldout_windows(heldout, window=9, windows=2, k=4)
    assert windows and set(windows) <= {"grass", "snow", "sand", "red_sand", "normal"}
    for w in windows.values():
        assert w.dtype == np.uint8 and w.shape[1:] == (9, 2, SIZE, SIZE, 3)
    with pytest.raises(ValueError, match="window must be 1 \\+ 4 \\* n frames"):
        AT.heldout_windows(heldout, window=8, windows=2, k=4)


def test_a_perfect_reconstruction_meets_both_targets_and_a_grey_one_neither(heldout, segments, judge):
    windows = AT.heldout_windows(heldout, window=9, windows=2, k=4)
    original = judge_episodes(judge, [s.episode for s in segments])
    perfect = AT.score_model(identity, windows, 4, segments, judge, original)
    assert perfect["psnr_db_min_surface"] > 100 and perfect["meets"] == {"psnr": True, "judges": True}
    assert len(perfect["psnr_db_by_latent"]) == 3 and min(perfect["psnr_db_by_latent"]) > 100  # frame 0, 2 chunks
    assert set(perfect["sharpness_ratio_by_surface"].values()) == {1.0}
    assert perfect["sharpness_ratio_min_surface"] == 1.0
    assert perfect["judges"]["max_abs_difference_points"] == 0
    assert all(q["same_answer"] == 1.0 for q in perfect["judges"]["answer_agreement"].values())
    assert perfect["judges"]["tasks_pct"]["original"] == perfect["judges"]["tasks_pct"]["reconstructed"]
    np.testing.assert_array_equal(perfect["_sample"][next(iter(windows))],
                                  windows[next(iter(windows))][0, 4])

    grey = AT.score_model(flat_grey, windows, 4, segments, judge, original)
    assert grey["psnr_db_min_surface"] < 20 and not grey["meets"]["psnr"]
    assert len(grey["psnr_db_by_latent"]) == 3 and max(grey["psnr_db_by_latent"]) < 20
    assert grey["sharpness_ratio_min_surface"] == 0.0  # a flat frame has no edges
    agreement = grey["judges"]["answer_agreement"]
    assert sum(q["queries"] for q in agreement.values()) == len(original)
    # the judges answer a flat frame differently from an engine view on some queries
    assert min(q["same_answer"] for q in agreement.values()) < 1.0


def test_the_cli_scores_a_random_model_and_writes_json_and_png(heldout, eval_data, tmp_path):
    out = tmp_path / "at.json"
    result = AT.main(["--model", "preset:test", "--heldout", str(heldout), "--eval", str(eval_data),
                      "--window", "9", "--windows", "1", "--out", str(out)])
    saved = json.loads(out.read_text())
    row = saved["models"]["preset test (random init)"]
    assert 0 < row["psnr_db_min_surface"] < 40 and row["meets"]["psnr"] is False
    assert row["psnr_db_min_surface"] == min(row["psnr_db_by_surface"].values())
    assert set(row["judges"]["difference_points"]) == set(row["judges"]["tasks_pct"]["original"])
    assert saved["table"] == result["table"] and "preset test" in saved["table"]
    assert out.with_suffix(".png").is_file()


def test_frames_of_another_size_fail_naming_the_flag(heldout, eval_data, tmp_path):
    with pytest.raises(ValueError, match="--heldout .*collect with --resolution 64"):
        AT.run({"x": identity}, heldout, eval_data, 9, 1, 4, (64, 64, 3))


def test_psnr_by_latent_finds_the_chunk_a_decoder_loses(heldout):
    windows = AT.heldout_windows(heldout, window=9, windows=1, k=4)

    def loses_chunk_two(obs_BTPHW3):  # frames 0 | 1-4 | 5-8: the second chunk comes out black
        rec = obs_BTPHW3.copy()
        rec[:, 5:9] = 0
        return rec

    psnr, by_latent, _, _ = AT.psnr_by_surface(loses_chunk_two, windows, k=4)
    assert by_latent[0] > 100 and by_latent[1] > 100 and by_latent[2] < 15
    assert all(v < 20 for v in psnr.values())
