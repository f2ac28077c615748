"""``benchmarks.action_response`` on the test preset (random weights): the real engine answers both probes."""

import json

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


def test_probe_action_rejects_unknown_probe():
    with pytest.raises(ValueError, match="probe must be one of"):
        action_response.probe_action("jump", 10.0)
