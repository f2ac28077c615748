"""``training/gpu_call.sh``, the GPU session's one call, run on the CPU with the ``test`` preset: the candidate
sprint and the official-layout control side by side, each returned as its shards plus one ``meta.tar``."""

import json
import os
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest

from solaris_env.world_model import checkpoint

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_gpu_call_returns_the_candidate_and_the_control_packed(tiny_duet, tmp_path):
    from solaris_env.world_model.components import COMPONENTS
    from solaris_env.world_model.world_model import WorldModel

    init_model = WorldModel.from_preset("test", seed=0)
    init = checkpoint.save(tmp_path / "init", init_model.config, dict(zip(COMPONENTS, init_model.params)),
                           storage_dtype="float16")
    for run in ("sprint", "control"):  # seeded with recorded episodes, so both train at once
        shutil.copytree(tiny_duet / "duet", tmp_path / "data" / run / "duet")
    out = tmp_path / "out"
    env = {**os.environ, "OUT": str(out), "PYTHON": sys.executable, "SPRINT_PRESET": "test", "SPRINT_INIT": str(init),
           "SPRINT_BUDGET_MIN": "2.5", "SPRINT_WORKERS": "1", "SPRINT_DATA": str(tmp_path / "data"),
           "TMPDIR": str(tmp_path)}
    done = subprocess.run(["bash", "training/gpu_call.sh"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "== sprint: exit 0" in done.stdout and "== control: exit 0" in done.stdout, done.stdout
    assert sorted(p.name for p in out.iterdir()) == ["control", "sprint"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("solaris-call.")]  # its scratch folder removed
    models = {}
    for run in ("sprint", "control"):
        files = sorted(str(p.relative_to(out / run)) for p in (out / run).rglob("*") if p.is_file())
        shards = [f for f in files if f.startswith("model/weights-")]
        assert files == sorted(shards + ["meta.tar"]) and shards, files
        with tarfile.open(out / run / "meta.tar") as tar:
            assert sorted(tar.getnames()) == ["log.txt", "model/config.json", "model/lineage.json"]
            tar.extractall(out / run, filter="data")
        assert "sprint: model written to" in (out / run / "log.txt").read_text()
        lineage = json.loads((out / run / "model" / "lineage.json").read_text())
        assert "--workers" in lineage["command"] and [s["status"] for s in lineage["stages"]].count("ran") == 1
        models[run] = WorldModel.load(out / run / "model")
    # the control kept the init's codec bit for bit and trained a fresh DiT of its own
    vae = [np.asarray(x) for x in _leaves(init_model, "vae")]
    for run, model in models.items():
        for a, b in zip(vae, [np.asarray(x) for x in _leaves(model, "vae")]):
            np.testing.assert_array_equal(a.astype(np.float16), b.astype(np.float16))
    dit = [np.asarray(x) for x in _leaves(models["sprint"], "dit")]
    assert any(not np.array_equal(a, b) for a, b in zip(dit, _leaves(models["control"], "dit")))


def _leaves(model, component: str):
    import jax

    from solaris_env.world_model.components import COMPONENTS

    return jax.tree.leaves(dict(zip(COMPONENTS, model.params))[component])
