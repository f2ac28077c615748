"""training/distributed.py: the train step of training/step.py on 4 (host-platform) CPU devices, data-parallel
and FSDP, against 1 device. The 4-device runs happen in a subprocess, since XLA_FLAGS must be set before JAX
starts; this file is also that subprocess's script (``python test_distributed.py worker OUT.json``).

The DiT is the ``test`` preset with random parameters drawn by numpy (its own initialisers would cost a
compile); batches are synthetic model inputs of the right shapes (B=4: one sample per device).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

NUM_DEVICES = 4
B = 4
NUM_STEPS = 3
LR = 1e-3
RTOL = 1e-5
# O0 halves the CPU time of compiling the DiT's train step; every run of the worker uses the same flags.
XLA_FLAGS = f"--xla_force_host_platform_device_count={NUM_DEVICES} --xla_backend_optimization_level=0"
REPO = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------
# Pure-host tests (no devices needed)
# ---------------------------------------------------------------------------------------------


def test_fsdp_spec_picks_largest_divisible_axis():
    from jax.sharding import PartitionSpec as P

    from training.distributed import fsdp_spec

    assert fsdp_spec((2, 64, 128), 4, min_size=0) == P(None, None, "data")
    assert fsdp_spec((2, 64, 64), 4, min_size=0) == P(None, "data")  # first of equal axes
    assert fsdp_spec((6, 3), 4, min_size=0) == P()  # nothing divisible
    assert fsdp_spec((), 4, min_size=0) == P()
    assert fsdp_spec((64, 64), 1, min_size=0) == P()  # one device
    assert fsdp_spec((4, 8), 4) == P()  # below the default min_size: replicated
    assert fsdp_spec((4096, 4), 4) == P("data")


def test_maybe_initialize_distributed_single_process_is_a_no_op():
    from training.distributed import maybe_initialize_distributed

    assert maybe_initialize_distributed({}) is False
    assert maybe_initialize_distributed({"JAX_NUM_PROCESSES": "1"}) is False
    with pytest.raises(ValueError, match="JAX_NUM_PROCESSES"):
        maybe_initialize_distributed({"JAX_NUM_PROCESSES": "two"})
    with pytest.raises(ValueError, match="JAX_PROCESS_ID"):
        maybe_initialize_distributed({"JAX_NUM_PROCESSES": "2", "JAX_PROCESS_ID": "5"})


# ---------------------------------------------------------------------------------------------
# The 4-device run (one subprocess for all tests below: ~60 s of CPU, three train-step compiles)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def four_devices(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist") / "result.json"
    env = dict(os.environ, XLA_FLAGS=XLA_FLAGS, JAX_PLATFORMS="cpu")
    proc = subprocess.run([sys.executable, __file__, "worker", str(out)], check=False, cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return json.loads(out.read_text())


@pytest.mark.slow
def test_worker_saw_four_devices(four_devices):
    assert four_devices["device_count"] == NUM_DEVICES


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["data", "fsdp"])
def test_same_losses_and_params_as_one_device(four_devices, mode):
    ref, run = four_devices["one_device"], four_devices[mode]
    assert len(run["losses"]) == NUM_STEPS
    np.testing.assert_allclose(run["losses"], ref["losses"], rtol=RTOL)
    # params after NUM_STEPS Adam steps: |p - p_ref| / |p_ref| per parameter array (Frobenius norms)
    assert max(run["param_rel_diff"].values()) < RTOL, sorted(run["param_rel_diff"].items(), key=lambda kv: -kv[1])[:5]
    assert run["step"] == NUM_STEPS


@pytest.mark.slow
def test_data_parallel_state_replicated_batch_split(four_devices):
    from jax.sharding import PartitionSpec as P

    run = four_devices["data"]
    assert run["param_specs"] == [str(P())]
    assert run["batch_spec"] == str(P("data"))
    assert run["batch_shard_rows"] == B // NUM_DEVICES
    assert re.search(r"batch\['\w+'\]: axis 0 has 3 rows, must be a multiple of the 4 devices", run["bad_rows_error"])


@pytest.mark.slow
def test_fsdp_params_and_moments_really_sharded(four_devices):
    run = four_devices["fsdp"]
    # every parameter of >= FSDP_MIN_SIZE elements with an axis divisible by 4 is split, and its Adam moments alike
    assert run["num_sharded_params"] >= 10, run
    assert run["num_sharded_params"] == run["num_expected_sharded"]
    assert run["moments_match_params"]
    assert run["shard_shape_ok"]
    assert run["step_and_rng_replicated"]
    assert run["output_specs_equal_input"]  # the state keeps its layout from step to step


@pytest.mark.slow
def test_sharded_checkpoint_restores_with_abstract_shardings(four_devices):
    run = four_devices["fsdp_checkpoint"]
    assert run["bit_exact"]
    assert run["shardings_match"]
    assert run["num_sharded_restored"] == four_devices["fsdp"]["num_sharded_params"]


# ---------------------------------------------------------------------------------------------
# Worker (runs in the subprocess)
# ---------------------------------------------------------------------------------------------


def _tiny_dit_state(lr: float):
    """(graphdef, host params, tx): the ``test``-preset DiT with numpy-drawn parameters."""
    import jax
    from flax import nnx

    from solaris_env.world_model.config import preset
    from solaris_env.world_model.dit import WorldDiT
    from training.step import make_optimizer

    cfg = preset("test")
    graphdef, abstract = nnx.split(nnx.eval_shape(lambda: WorldDiT(cfg, rngs=nnx.Rngs(0))))
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda x: (rng.normal(size=x.shape) * 0.05).astype(x.dtype), abstract)
    return cfg, graphdef, params, make_optimizer(lr)


def _synthetic_batch(cfg, batch_size: int, seed: int) -> dict[str, np.ndarray]:
    from solaris_env.world_model.action_module import padded_action_length

    rng = np.random.default_rng(seed)
    p, f, h, w = cfg.num_players, 2, cfg.latent_height, cfg.latent_width
    t_pad = padded_action_length(cfg, f)
    batch = {"x0": rng.normal(size=(batch_size, p, f, h, w, cfg.latent_channels)),
             "cond": rng.normal(size=(batch_size, p, f, h, w, cfg.in_channels - cfg.out_channels)),
             "context": rng.normal(size=(batch_size, p, cfg.image_encoder.num_tokens, cfg.context_width)),
             "mouse": rng.normal(size=(batch_size, p, t_pad, 2)),
             "keyboard": rng.integers(0, 2, (batch_size, p, t_pad, 23))}
    return {k: v.astype(np.float32) for k, v in batch.items()}


def worker(out_path: str) -> None:
    import tempfile

    import jax
    import jax.numpy as jnp
    from flax import nnx

    from training import distributed as dist
    from training.checkpointing import Checkpointer, tree_paths
    from training.step import TrainState, make_train_step

    cfg, graphdef, host_params, tx = _tiny_dit_state(LR)
    batches = [_synthetic_batch(cfg, B, seed) for seed in range(NUM_STEPS)]

    def fresh_state():
        return TrainState.create(nnx.merge(graphdef, jax.tree.map(jnp.asarray, host_params)), tx, rng=0)

    graphdef, _ = fresh_state()
    train_step = make_train_step(graphdef, "forward_bidirectional", "standard", tx)

    def run(step_fn, state, batches):
        losses = []
        for batch in batches:
            state, metrics = step_fn(state, batch)
            losses.append(float(metrics["loss"]))
        return state, losses

    result = {"device_count": jax.device_count()}
    ref_state, ref_losses = run(train_step, fresh_state()[1], [jax.device_put(b) for b in batches])  # device 0
    ref_params = {k: np.asarray(v) for k, v in tree_paths(ref_state.params).items()}
    result["one_device"] = {"losses": ref_losses}

    def summary(state, losses):
        params = tree_paths(state.params)
        rel = {k: float(np.linalg.norm(np.asarray(v) - ref_params[k]) / max(np.linalg.norm(ref_params[k]), 1e-30))
               for k, v in params.items()}
        return {"losses": losses, "param_rel_diff": rel, "step": int(state.step),
                "param_specs": sorted({str(v.sharding.spec) for v in params.values()})}

    mesh = dist.make_mesh(NUM_DEVICES)

    # data parallel: step.py's jitted step, unchanged, on a replicated state and a split batch
    state = dist.shard_train_state(fresh_state()[1], mesh, fsdp=False)
    sharded_batches = [dist.shard_batch(b, mesh) for b in batches]
    first = sharded_batches[0]["x0"]
    state, losses = run(train_step, state, sharded_batches)
    try:
        dist.shard_batch(_synthetic_batch(cfg, B - 1, 0), mesh)
        bad_rows_error = ""
    except ValueError as err:
        bad_rows_error = str(err)
    result["data"] = dict(summary(state, losses), batch_spec=str(first.sharding.spec),
                          batch_shard_rows=int(first.addressable_shards[0].data.shape[0]),
                          bad_rows_error=bad_rows_error)

    # FSDP: the same step pinned to the FSDP layout by distribute_train_step
    state = dist.shard_train_state(fresh_state()[1], mesh, fsdp=True)
    in_specs = [x.sharding.spec for x in jax.tree.leaves(state)]
    fsdp_step = dist.distribute_train_step(train_step, state, mesh, fsdp=True)
    state, losses = run(fsdp_step, state, sharded_batches)
    params, mu = tree_paths(state.params), tree_paths(state.opt_state[0].mu)
    sharded = {k for k, v in params.items() if not v.sharding.is_fully_replicated}
    expected = {k for k, v in params.items()
                if dist.fsdp_spec(v.shape, NUM_DEVICES) != jax.sharding.PartitionSpec()}
    shard_ok = all(
        v.addressable_shards[0].data.shape[list(v.sharding.spec).index("data")]
        == v.shape[list(v.sharding.spec).index("data")] // NUM_DEVICES for k, v in params.items() if k in sharded)
    result["fsdp"] = dict(
        summary(state, losses), num_sharded_params=len(sharded), num_expected_sharded=len(expected & sharded),
        moments_match_params=all(mu[k].sharding == params[k].sharding for k in params),
        shard_shape_ok=bool(shard_ok and sharded == expected),
        step_and_rng_replicated=bool(state.step.sharding.is_fully_replicated and state.rng.sharding.is_fully_replicated),
        output_specs_equal_input=[x.sharding.spec for x in jax.tree.leaves(state)] == in_specs)

    # checkpoint of the FSDP state, restored into an abstract state carrying the FSDP shardings
    host = jax.device_get(state)
    with tempfile.TemporaryDirectory() as tmp, Checkpointer(tmp, keep=1) as ckpt:
        ckpt.save(NUM_STEPS, state, {"stage": "test"})
        abstract = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding), state)
        restored, extra = ckpt.restore(NUM_STEPS, abstract)
    pairs = list(zip(jax.tree.leaves(restored), jax.tree.leaves(host), jax.tree.leaves(abstract)))
    result["fsdp_checkpoint"] = {
        "bit_exact": all(np.array_equal(np.asarray(r), h) and r.dtype == h.dtype for r, h, _ in pairs)
        and extra == {"stage": "test"},
        "shardings_match": all(r.sharding == a.sharding for r, _, a in pairs),
        "num_sharded_restored": sum(not v.sharding.is_fully_replicated for v in jax.tree.leaves(restored.params)),
    }
    Path(out_path).write_text(json.dumps(result))


if __name__ == "__main__" and len(sys.argv) == 3 and sys.argv[1] == "worker":
    worker(sys.argv[2])
