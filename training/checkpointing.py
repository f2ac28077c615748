"""Training-state checkpoints (docs/training.md, docs/model.md §9): orbax step directories holding a
train-state pytree and a JSON ``extra`` dict (data-sampler state, stage name, config), written together.

    ckpt = Checkpointer(stage_dir / "checkpoints", keep=3)
    if (latest := ckpt.latest_step()) is not None:
        state, extra = ckpt.restore(latest, jax.eval_shape(lambda: fresh_state))
        sampler.load_state_dict(extra["sampler"])
    ...
    ckpt.save(step, state, {"sampler": sampler.state_dict(), "stage": "mp-causal"})
    ckpt.close()

Layout: ``{directory}/{step}/state`` (orbax ``StandardSave`` of the pytree: a ``TrainState``, or e.g.
``{"generator": TrainState, "critic": TrainState}`` for Self Forcing) and ``{directory}/{step}/extra``
(``JsonSave``). A save is written under ``{step}.orbax-checkpoint-tmp-*`` and renamed into place only when
complete, so a save interrupted at any point (even ``kill -9``) never leaves a directory that
:meth:`Checkpointer.latest_step` returns; leftover temporary directories are removed by the next
``Checkpointer`` on the same directory. Saves are synchronous: when :meth:`Checkpointer.save` returns the
checkpoint is final and the saved arrays may be donated to the next train step.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Self

import jax
import numpy as np
import orbax.checkpoint as ocp
from orbax.checkpoint import checkpoint_managers as ocm

STATE_ITEM = "state"
EXTRA_ITEM = "extra"
_MAX_LISTED = 8  # keys named in a tree-mismatch error


class CheckpointMismatchError(ValueError):
    """The checkpoint on disk holds a different tree (keys, shapes or dtypes) than the one asked for."""


def _key_name(key) -> str:
    for attr in ("name", "key", "idx"):
        if hasattr(key, attr):
            return str(getattr(key, attr))
    return str(key)


def tree_paths(tree: Any, is_leaf=None) -> dict[str, Any]:
    """``{"params.blocks.attn.q.kernel.value": leaf, ...}``: dotted key paths (orbax's naming) -> leaves."""
    flat, _ = jax.tree_util.tree_flatten_with_path(tree, is_leaf=is_leaf)
    return {".".join(_key_name(k) for k in path): leaf for path, leaf in flat}


def abstract_state(state: Any) -> Any:
    """``state``'s restore target: a ``jax.ShapeDtypeStruct`` (shape, dtype, sharding) per array leaf.

    Restoring into it gives arrays placed exactly like ``state``'s, so a resumed run feeds the train step
    the same shardings as a fresh one (and runs the same compiled program). Place the fresh state first
    (``training.distributed.shard_train_state``, also on one device): an unplaced array's default
    placement compiles differently from the committed arrays a restore returns.
    """
    return jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=getattr(x, "sharding", None)),
                        state)


def _abstract_leaf(x: Any) -> jax.ShapeDtypeStruct:
    """A restore target: shape, dtype and sharding (the first local device when the leaf carries none)."""
    sharding = getattr(x, "sharding", None)
    if sharding is None:
        sharding = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
    return jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=sharding)


def _json_roundtrip(extra: dict) -> dict:
    if not isinstance(extra, dict):
        raise TypeError(f"extra must be a dict, got {type(extra).__name__}")
    try:
        return json.loads(json.dumps(extra, allow_nan=False))
    except (TypeError, ValueError) as err:
        bad = [k for k, v in extra.items() if not _json_ok(v)]
        raise ValueError(f"extra must be JSON-serialisable (plain dicts/lists/str/int/float/bool/None, finite "
                         f"floats); offending keys {bad}: {err}") from None


def _json_ok(value: Any) -> bool:
    try:
        json.dumps(value, allow_nan=False)
        return True
    except (TypeError, ValueError):
        return False


class Checkpointer:
    """Step-numbered checkpoints of a train-state pytree plus a JSON ``extra`` dict, in one directory.

    Args:
        directory: the checkpoint root (created); step directories are named by the step number.
        keep: how many of the most recent checkpoints to keep (older ones are deleted after a save).
        keep_period: additionally keep every checkpoint whose step is a multiple of this (e.g. 20000,
            docs/training.md); None keeps only the ``keep`` latest.
    """

    def __init__(self, directory: str | Path, keep: int = 3, keep_period: int | None = None) -> None:
        if int(keep) < 1:
            raise ValueError(f"keep must be >= 1, got {keep}")
        if keep_period is not None and int(keep_period) < 1:
            raise ValueError(f"keep_period must be >= 1 or None, got {keep_period}")
        self.directory = Path(directory).absolute()
        self.keep, self.keep_period = int(keep), keep_period
        policies: list = [ocm.LatestN(n=self.keep)]
        if keep_period is not None:
            policies.append(ocm.EveryNSteps(interval_steps=int(keep_period)))
        options = ocp.CheckpointManagerOptions(
            create=True,
            cleanup_tmp_directories=True,  # remove what an interrupted save left behind
            enable_async_checkpointing=False,  # save() returns a final checkpoint
            preservation_policy=ocm.AnyPreservationPolicy(policies),
        )
        self._manager = ocp.CheckpointManager(
            self.directory, options=options,
            item_handlers={STATE_ITEM: ocp.StandardCheckpointHandler(), EXTRA_ITEM: ocp.JsonCheckpointHandler()})
        # orbax removes leftover temporary directories in a background thread and waits for it only in
        # save(); wait now so the directory is clean when the constructor returns
        getattr(self._manager, "_maybe_await_cleanup_tmp_directory", lambda: None)()

    # -- queries ---------------------------------------------------------------------------------

    def all_steps(self) -> list[int]:
        """Steps of the complete checkpoints on disk, ascending."""
        self._manager.reload()
        return sorted(int(s) for s in self._manager.all_steps())

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None when there is none."""
        steps = self.all_steps()
        return steps[-1] if steps else None

    # -- save / restore ----------------------------------------------------------------------------

    def save(self, step: int, state: Any, extra: dict | None = None) -> None:
        """Write ``state`` (any pytree of arrays) and ``extra`` (a JSON-able dict) as checkpoint ``step``.

        Returns when the checkpoint is complete on disk (then old ones beyond ``keep`` are pruned).
        Raises ValueError if ``step`` is already saved or ``extra`` is not JSON-serialisable.
        """
        step = int(step)
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        extra = _json_roundtrip({} if extra is None else extra)
        if step in self.all_steps():
            raise ValueError(f"checkpoint step {step} already exists in {self.directory}")
        self._manager.save(step, args=ocp.args.Composite(**{
            STATE_ITEM: ocp.args.StandardSave(state), EXTRA_ITEM: ocp.args.JsonSave(extra)}), force=True)
        self._manager.wait_until_finished()

    def restore(self, step: int, abstract_state: Any) -> tuple[Any, dict]:
        """Read checkpoint ``step`` -> ``(state, extra)``.

        Args:
            step: a step of :meth:`all_steps`.
            abstract_state: the tree to restore into: :func:`abstract_state` of a fresh state (keeps its
                shardings), ``jax.eval_shape(lambda: fresh_state)``, or a concrete state; leaves give shape,
                dtype and sharding (a leaf without a sharding is restored onto the first local device).
                The result has this tree's structure (pytree types).
        Raises:
            FileNotFoundError: no complete checkpoint ``step``.
            CheckpointMismatchError: the saved tree has other keys, shapes or dtypes (names them).
        """
        step = int(step)
        steps = self.all_steps()
        if step not in steps:
            raise FileNotFoundError(f"no checkpoint step {step} in {self.directory} (complete steps: {steps})")
        target = jax.tree.map(_abstract_leaf, abstract_state)
        self._check_tree(step, target)
        restored = self._manager.restore(step, args=ocp.args.Composite(**{
            STATE_ITEM: ocp.args.StandardRestore(target), EXTRA_ITEM: ocp.args.JsonRestore()}))
        return restored[STATE_ITEM], dict(restored[EXTRA_ITEM] or {})

    def _check_tree(self, step: int, target: Any) -> None:
        metadata = self._manager.item_metadata(step)[STATE_ITEM]
        saved_tree = getattr(metadata, "tree", metadata)
        saved = tree_paths(saved_tree, is_leaf=lambda x: hasattr(x, "shape") and hasattr(x, "dtype"))
        wanted = tree_paths(target)
        missing = sorted(set(wanted) - set(saved))
        unexpected = sorted(set(saved) - set(wanted))
        problems = []
        if missing:
            problems.append(f"{len(missing)} key(s) missing from the checkpoint: {missing[:_MAX_LISTED]}")
        if unexpected:
            problems.append(f"{len(unexpected)} unexpected key(s) in the checkpoint: {unexpected[:_MAX_LISTED]}")
        mismatched = [f"{k}: saved {tuple(saved[k].shape)} {np.dtype(saved[k].dtype)}, expected "
                      f"{tuple(wanted[k].shape)} {np.dtype(wanted[k].dtype)}"
                      for k in sorted(set(saved) & set(wanted))
                      if tuple(saved[k].shape) != tuple(wanted[k].shape)
                      or np.dtype(saved[k].dtype) != np.dtype(wanted[k].dtype)]
        if mismatched:
            problems.append(f"{len(mismatched)} shape/dtype mismatch(es): {mismatched[:_MAX_LISTED]}")
        if problems:
            raise CheckpointMismatchError(f"checkpoint {self.directory / str(step)} holds a different tree than "
                                          f"the state to restore: " + "; ".join(problems))

    # -- lifecycle -------------------------------------------------------------------------------

    def close(self) -> None:
        self._manager.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
