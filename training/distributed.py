"""Data-parallel SPMD training over a 1-D ``"data"`` mesh (docs/training.md), optionally FSDP-sharded.

    maybe_initialize_distributed()              # multi-host only; before any other JAX call
    mesh = make_mesh()                          # all devices on the "data" axis
    state = shard_train_state(state, mesh, fsdp=False)   # replicated, as the reference
    train_step = distribute_train_step(make_train_step(graphdef, entry, noise, tx), state, mesh)
    state, metrics = train_step(state, shard_batch(batch, mesh))

The batch axis (axis 0 of every batch array) is split over ``"data"``; the train state is either fully
replicated (the reference: per-device batch, model and optimiser replicated) or, with ``fsdp=True``,
each parameter and its optimiser moments are split along their largest axis divisible by the device
count (others, and scalars such as ``step``, replicated). The jitted step of ``training/step.py`` runs
unchanged: XLA's SPMD partitioner inserts the gradient all-reduce (and for FSDP the all-gathers /
reduce-scatters). :func:`distribute_train_step` only pins the step's output state to the input state's
shardings, so the state keeps its layout from step to step and donation reuses its buffers.

Multi-host: every process runs the same program on its local devices; :func:`shard_batch` takes the
process-local rows (``global batch / process_count``) and assembles the global array.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from training.step import TrainState

logger = logging.getLogger(__name__)

DATA_AXIS = "data"
FSDP_MIN_SIZE = 1024  # arrays with fewer elements stay replicated under FSDP
# Environment of a multi-process run (our names; jax itself reads JAX_COORDINATOR_ADDRESS).
ENV_COORDINATOR = "JAX_COORDINATOR_ADDRESS"
ENV_NUM_PROCESSES = "JAX_NUM_PROCESSES"
ENV_PROCESS_ID = "JAX_PROCESS_ID"


def maybe_initialize_distributed(environ: dict[str, str] | None = None) -> bool:
    """Call ``jax.distributed.initialize()`` when the environment describes a multi-process run.

    A run is multi-process when ``JAX_COORDINATOR_ADDRESS`` is set or ``JAX_NUM_PROCESSES`` > 1;
    ``JAX_NUM_PROCESSES`` / ``JAX_PROCESS_ID`` are passed on when set (else JAX's cluster auto-detection,
    e.g. SLURM or Open MPI, fills them). Must run before any other JAX call. Idempotent.
    Returns True when JAX is (now) initialised for several processes.
    """
    env = os.environ if environ is None else environ
    coordinator = env.get(ENV_COORDINATOR)
    num_processes = _env_int(env, ENV_NUM_PROCESSES)
    process_id = _env_int(env, ENV_PROCESS_ID)
    if coordinator is None and (num_processes is None or num_processes <= 1):
        return False
    if jax.distributed.is_initialized():
        return True
    if num_processes is not None and process_id is not None and not 0 <= process_id < num_processes:
        raise ValueError(f"{ENV_PROCESS_ID}={process_id} must be in [0, {ENV_NUM_PROCESSES}={num_processes})")
    jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes, process_id=process_id)
    logger.info("jax.distributed: process %d of %d, %d local / %d global devices", jax.process_index(),
                jax.process_count(), jax.local_device_count(), jax.device_count())
    return True


def _env_int(env, name: str) -> int | None:
    value = env.get(name)
    if value is None or value == "":
        return None
    try:
        return int(value)
    except ValueError:
        raise ValueError(f"{name} must be an integer, got {value!r}") from None


# ---------------------------------------------------------------------------------------------
# Mesh and shardings
# ---------------------------------------------------------------------------------------------


def make_mesh(num_devices: int | None = None) -> Mesh:
    """A 1-D mesh with axis ``"data"`` over the first ``num_devices`` devices (default: all, every host)."""
    devices = jax.devices()
    n = len(devices) if num_devices is None else int(num_devices)
    if not 1 <= n <= len(devices):
        raise ValueError(f"num_devices must be in [1, {len(devices)}] (jax.devices()), got {num_devices}")
    if n < len(devices) and jax.process_count() > 1:
        raise ValueError(f"num_devices={n} < {len(devices)}: a multi-process mesh must hold every device")
    return Mesh(np.asarray(devices[:n]), (DATA_AXIS,))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, PartitionSpec())


def batch_sharding(mesh: Mesh) -> NamedSharding:
    """Axis 0 split over ``"data"``, the other axes whole."""
    return NamedSharding(mesh, PartitionSpec(DATA_AXIS))


def fsdp_spec(shape: tuple[int, ...], num_shards: int, min_size: int = FSDP_MIN_SIZE) -> PartitionSpec:
    """Split the largest axis whose size is a multiple of ``num_shards`` (the first of equal ones) over
    ``"data"``; ``PartitionSpec()`` (replicated) when none is, for one shard, and for arrays of fewer than
    ``min_size`` elements (scalars, biases, norms: not worth a collective)."""
    if num_shards <= 1 or math.prod(shape) < min_size:
        return PartitionSpec()
    candidates = [(size, -axis) for axis, size in enumerate(shape) if size % num_shards == 0]
    if not candidates:
        return PartitionSpec()
    axis = -max(candidates)[1]
    return PartitionSpec(*([None] * axis), DATA_AXIS)


def state_shardings(state: Any, mesh: Mesh, fsdp: bool = False, min_size: int = FSDP_MIN_SIZE) -> Any:
    """Shardings (a pytree of ``NamedSharding`` like ``state``) for a train state or any pytree of them.

    Usable as jit ``in_shardings`` / ``out_shardings`` and with ``jax.device_put``; ``state`` may be
    abstract (``jax.eval_shape``). Replicated unless ``fsdp``; with ``fsdp`` every array leaf follows
    :func:`fsdp_spec` (so a parameter and its Adam moments are split alike), except a ``TrainState``'s
    ``step`` and ``rng``, which stay replicated; ``min_size`` as in :func:`fsdp_spec`.
    """
    rep = replicated(mesh)
    if not fsdp:
        return jax.tree.map(lambda _: rep, state)
    n = mesh.shape[DATA_AXIS]
    leaf_sharding = lambda x: NamedSharding(mesh, fsdp_spec(tuple(np.shape(x)), n, min_size))

    def one(node):
        if isinstance(node, TrainState):
            return TrainState(params=jax.tree.map(leaf_sharding, node.params),
                              rest=jax.tree.map(leaf_sharding, node.rest),
                              opt_state=jax.tree.map(leaf_sharding, node.opt_state), step=rep, rng=rep)
        return leaf_sharding(node)

    return jax.tree.map(one, state, is_leaf=lambda x: isinstance(x, TrainState))


def shard_train_state(state: Any, mesh: Mesh, fsdp: bool = False, min_size: int = FSDP_MIN_SIZE) -> Any:
    """Place ``state`` on ``mesh`` (:func:`state_shardings`)."""
    return jax.device_put(state, state_shardings(state, mesh, fsdp, min_size))


def shard_batch(batch: Any, mesh: Mesh) -> Any:
    """Split axis 0 of every array of ``batch`` over ``"data"``.

    Single process: ``batch`` is the global batch. Multi-process: it is this process's rows (the global
    batch is the processes' rows in process order). The row count must be a multiple of the number of
    devices the process feeds.
    """
    sharding = batch_sharding(mesh)
    multi = jax.process_count() > 1
    local = len([d for d in mesh.devices.flat if d.process_index == jax.process_index()])

    def one(path, x):
        rows = np.shape(x)[0] if np.ndim(x) else None
        if rows is None or rows % local:
            name = jax.tree_util.keystr(path)
            raise ValueError(f"batch{name}: axis 0 has {rows} rows, must be a multiple of the {local} "
                             f"{'local ' if multi else ''}devices of the mesh")
        if multi:
            return jax.make_array_from_process_local_data(sharding, np.asarray(x))
        return jax.device_put(x, sharding)

    return jax.tree_util.tree_map_with_path(one, batch)


def distribute_train_step(train_step: Callable, state: Any, mesh: Mesh, fsdp: bool = False,
                          min_size: int = FSDP_MIN_SIZE) -> Callable:
    """Wrap a (jitted) ``train_step(state, batch) -> (state, metrics)`` for the mesh: input and output
    state pinned to :func:`state_shardings`, batch split over ``"data"``, metrics replicated, state donated.

    ``state`` (concrete or abstract) only gives the tree; the wrapped step is one compiled program.
    """
    shardings = state_shardings(state, mesh, fsdp, min_size)
    return jax.jit(train_step, in_shardings=(shardings, batch_sharding(mesh)),
                   out_shardings=(shardings, replicated(mesh)), donate_argnums=(0,))
