"""``solaris_env.paths``: the repository root, and what scripts write is never an absolute path (a path under the
repository becomes repository-relative, one outside keeps only its last components)."""

from pathlib import Path

import pytest

from solaris_env.paths import REPO_ROOT, portable_path, portable_text

ROOT = Path(__file__).resolve().parents[2]


def test_repo_root_is_this_checkout():
    assert REPO_ROOT == ROOT


def test_a_path_under_the_repository_becomes_repository_relative(monkeypatch):
    assert portable_path(ROOT / "runs" / "all15" / "self-forcing" / "model") == "runs/all15/self-forcing/model"
    assert portable_path(str(ROOT / "data" / "tiny320")) == "data/tiny320"
    assert portable_path(ROOT) == "."
    monkeypatch.chdir(ROOT / "docs")  # a relative path counts from the current directory
    assert portable_path("../benchmarks/results/policy_eval.json") == "benchmarks/results/policy_eval.json"


def test_a_path_outside_the_repository_keeps_only_its_last_components(tmp_path):
    outside = tmp_path / "runs" / "all8" / "self-forcing" / "model"
    assert not outside.is_relative_to(ROOT)
    assert portable_path(outside) == "self-forcing/model"
    assert portable_path(outside, parts=3) == "all8/self-forcing/model"
    assert portable_path("/work/runs/all8") == "runs/all8"
    assert portable_path("/data") == "data" and portable_path("/") == "."
    for p in (outside, "/tmp/dream", "~/runs/x", "/"):
        assert not portable_path(p).startswith(("/", "~"))
    with pytest.raises(ValueError):
        portable_path(outside, parts=0)


def test_portable_text_replaces_only_absolute_paths():
    cmd = ("python -m agents.evaluate --ppo-checkpoints /work/runs/agents/ppo-s1/checkpoints/step_1.zip "
           f"--checkpoint {ROOT}/runs/x/model --out=/tmp/pe/policy_eval.json")
    assert portable_text(cmd, parts=3) == ("python -m agents.evaluate --ppo-checkpoints ppo-s1/checkpoints/step_1.zip "
                                           "--checkpoint runs/x/model --out=tmp/pe/policy_eval.json")
    assert portable_text("ppo:/work/runs/agents/ppo-s1/checkpoints/step_1.zip", parts=3) == (
        "ppo:ppo-s1/checkpoints/step_1.zip")
    for unchanged in ("default", "preset:tiny16", "preset:test", "runs/x/model", "ppo:runs/a/step_1.zip",
                      "8 / 16", "http://127.0.0.1:8765/", "steps/s"):
        assert portable_text(unchanged) == unchanged
