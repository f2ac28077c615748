"""``benchmarks.action_response`` on the test preset (random weights): the real engine answers both probes."""

import json

import numpy as np
import pytest

from benchmarks import action_response


def test_action_response_measures_real_and_dream(tmp_path):
    out = tmp_path / "r.json"
    result = action_response.main(["--preset", "test", "--episodes", "1", "--steps", "3", "--out", str(out)])
    assert json.loads(out.read_text())["probes"].keys() == {"yaw", "forward"}
    for probe in ("yaw", "forward"):
        row = result["probes"][probe]
        assert len(row["real"]["by_step"]) == len(row["dream"]["by_step"]) == 3
        assert row["dream"]["mean"] >= 0
    assert result["probes"]["yaw"]["real"]["mean"] > 1.0  # a 10-degree turn moves the engine's view
    assert len(result["probes"]["yaw"]["dream"]["shift_px_by_step"]) == 3


def test_probe_action_rejects_unknown_probe():
    with pytest.raises(ValueError, match="probe must be one of"):
        action_response.probe_action("jump", 10.0)


def test_horizontal_shift_finds_how_far_the_content_moved():
    rng = np.random.default_rng(0)
    frame = np.repeat(rng.uniform(0, 255, (1, 64, 1)), 64, axis=0)  # vertical stripes: only columns differ
    frame = np.repeat(frame, 3, axis=2)
    for d in (-4, 0, 3):
        assert action_response.horizontal_shift(frame, np.roll(frame, d, axis=1)) == d
    acting = np.stack([frame, np.roll(frame, 2, axis=1), np.roll(frame, 5, axis=1)])[None]
    np.testing.assert_allclose(action_response.yaw_shift(acting), [2.0, 3.0])
