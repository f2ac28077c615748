"""World-model checkpoints: our format (safetensors + JSON) and the official orbax directories (docs/model.md §9).

Ours: a directory with

- ``config.json``: ``{"format": FORMAT, "version": VERSION, "components": [...], "config": {...}}``, the
  ``WorldModelConfig`` as nested dicts (tuples as lists);
- ``weights.safetensors``: every parameter of the three networks under its flattened NNX state path,
  prefixed by the component: ``dit/blocks/self_attn/q/kernel``, ``vae/encoder/conv_in/kernel``,
  ``image_encoder/blocks/0/fc1/kernel`` (list indices are path components);
- or, saved with ``shard_bytes``, the same tensors split over ``weights-00001-of-0000N.safetensors`` ..
  ``weights-0000N-of-0000N.safetensors``, each file at most ``shard_bytes`` (whole tensors, packed in key
  order; for transports that cap the file size). ``load`` reads either layout; a directory holding both,
  or an incomplete shard set, is an error.

It is written into a temporary directory next to the target and moved into place with ``os.replace``
(an existing checkpoint is first moved aside and deleted only after the new one is in place), so a
reader never sees a half-written checkpoint. Loading builds the networks abstractly from the saved
config (``nnx.eval_shape``: no initialisation compute), checks every key, shape and dtype, and raises
ONE ``ValueError`` listing all missing, unexpected and mis-shaped keys.

Legacy checkpoints (one rule, ``LEGACY_REFINER``). Checkpoints written before the temporal refiner was
deleted (the shipped default among them) carry its config block ``config.vae.refiner`` and, when it was
trained, its weights ``vae/refiner/...``. A config with that block is read without it (``read_config``), and
``load`` then drops every tensor under ``vae/refiner/`` and logs one INFO line naming how many it dropped.
Nothing else is ever dropped: any other unknown config field, a ``vae/refiner/`` tensor in a checkpoint
whose config has no such block, or any other unexpected tensor still raises.

Official: a directory holding the orbax ``StandardCheckpointer`` directories ``solaris.pt`` (the DiT),
``vae.pt`` and ``clip.pt`` (despite the suffix, not torch pickles; nothing is ever unpickled). Each holds
an NNX ``State`` saved by orbax, so every leaf path ends in ``value`` (``blocks/modulation/value``);
a pure-dict layout without that suffix is accepted too. ``solaris.pt`` must match our ``WorldDiT`` tree
exactly (the official tree, ``tests/solaris_env/world_model/fixtures/solaris-param-tree.txt``); ``vae.pt`` and
``clip.pt`` must match the reference VAE / CLIP trees, which ``official`` maps onto our modules. All
three trees are checked before anything is restored, and one ``ValueError`` lists every missing,
unexpected and mis-shaped key of every file. Values are restored by orbax and cast to the config's
``param_dtype`` (the official ``proj_mouse`` is bf16, the VAE mostly bf16).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import pathlib
import re
import shutil
import tempfile
import typing

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from solaris_env.world_model import config as config_lib
from solaris_env.world_model import official
from solaris_env.world_model.components import COMPONENTS, abstract_modules
from solaris_env.world_model.config import WorldModelConfig

FORMAT = "solaris_env.world_model"
VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "weights.safetensors"
SHARD_FILE = "weights-{index:05d}-of-{count:05d}.safetensors"
SHARD_RE = re.compile(r"weights-(\d{5})-of-(\d{5})\.safetensors")
OFFICIAL_FILES = {"dit": "solaris.pt", "vae": "vae.pt", "image_encoder": "clip.pt"}
LEGACY_REFINER = "refiner"  # the deleted temporal refiner: config.vae.refiner and the tensors vae/refiner/...

logger = logging.getLogger(__name__)

# ---------------------------------------------------------------------------------------------
# Config <-> JSON
# ---------------------------------------------------------------------------------------------


def config_to_dict(cfg) -> dict:
    """A (nested) config dataclass -> JSON-ready dict (tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def _from_value(tp, value, where: str):
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return config_from_dict(value, tp, where)
    if tp is tuple or origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"config field {where} must be a list, got {value!r}")
        return tuple(value)
    return value


# Fields deleted from the config (options that measured no gain), with the one value that the code now always
# uses: a checkpoint written before the deletion loads when it has that value, and fails naming the field otherwise.
RETIRED_FIELDS = {"SamplerConfig": {"renoise_eta": 1.0, "action_guidance": 1.0}}


def config_from_dict(data: dict, cls=WorldModelConfig, where: str = "config"):
    """Inverse of ``config_to_dict``; unknown or missing fields raise ValueError naming them (a retired field,
    ``RETIRED_FIELDS``, is accepted at the value the code now uses)."""
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a JSON object, got {type(data).__name__}")
    retired = RETIRED_FIELDS.get(cls.__name__, {})
    for name in sorted(set(data) & set(retired)):
        if data[name] != retired[name]:
            raise ValueError(f"{where}.{name} = {data[name]!r}: this option was removed (it measured no gain); "
                             f"only {retired[name]!r} loads, the behaviour the code now has")
    data = {name: value for name, value in data.items() if name not in retired}
    hints = typing.get_type_hints(cls, vars(config_lib))
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ValueError(f"{where} has unknown fields {unknown} for {cls.__name__}")
    kwargs = {name: _from_value(hints[name], value, f"{where}.{name}") for name, value in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as err:  # a required field is missing
        raise ValueError(f"{where}: {err}") from err


# ---------------------------------------------------------------------------------------------
# Flat parameter trees and the one strict check
# ---------------------------------------------------------------------------------------------


def flat_params(state) -> dict[str, jax.Array]:
    """NNX state -> {'a/b/c': array}."""
    return {"/".join(map(str, path)): v.get_value() if isinstance(v, nnx.Variable) else v
            for path, v in nnx.to_flat_state(state)}


def _spec(a) -> tuple[tuple[int, ...], str]:
    return tuple(int(d) for d in a.shape), str(np.dtype(a.dtype))


def check_tree(expected: dict[str, tuple], found: dict[str, tuple], where: str, check_dtype: bool = True) -> None:
    """Compare {key: (shape, dtype)} maps; raise ONE ValueError listing missing, unexpected and
    mis-shaped (or, with ``check_dtype``, mis-typed) keys."""
    official.check_tree(expected, found, f"checkpoint {where}", check_dtype=check_dtype, against="the model")


def _abstract(config: WorldModelConfig) -> dict[str, tuple]:
    """{component: (graphdef, abstract state)}."""
    return {name: nnx.split(m) for name, m in zip(COMPONENTS, abstract_modules(config))}


def _merge(graphdef, abstract_state, values: dict[str, jax.Array]):
    flat = [(path, values["/".join(map(str, path))]) for path, _ in nnx.to_flat_state(abstract_state)]
    return nnx.merge(graphdef, nnx.from_flat_state(flat))


# ---------------------------------------------------------------------------------------------
# Ours: safetensors + JSON
# ---------------------------------------------------------------------------------------------


STORAGE_DTYPES = (None, "float16")


def save(path, config: WorldModelConfig, params: dict, storage_dtype: str | None = None,
         shard_bytes: int | None = None, max_total_bytes: int | None = None,
         extra_files: dict[str, str] | None = None) -> pathlib.Path:
    """Write ``params`` ({component: NNX state}) and ``config`` to directory ``path`` atomically.

    ``storage_dtype="float16"`` stores float32 parameters in half precision (half the size, e.g. for the
    shipped model); ``load`` casts them back to the model's dtypes. Values outside the float16 range are
    an error, never silently clipped. ``shard_bytes`` splits the weights into shard files of at most that
    many bytes (module docstring); ``max_total_bytes`` refuses (ValueError, nothing replaced) weights
    larger than that in all; ``extra_files`` ({name: text}) are written into the same directory, atomically
    with the weights (e.g. a lineage record)."""
    from safetensors.numpy import save_file

    if storage_dtype not in STORAGE_DTYPES:
        raise ValueError(f"storage_dtype must be one of {STORAGE_DTYPES}, got {storage_dtype!r}")
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tensors = {f"{name}/{key}": np.ascontiguousarray(np.asarray(value))
               for name, state in params.items() for key, value in flat_params(state).items()}
    if storage_dtype is not None:
        for key, value in tensors.items():
            if value.dtype == np.float32:
                if np.abs(value).max(initial=0.0) > np.finfo(np.float16).max:
                    raise ValueError(f"{key}: values exceed the float16 range; save with storage_dtype=None")
                tensors[key] = value.astype(np.float16)
    file_meta = {"format": FORMAT, "version": str(VERSION)}
    files = {WEIGHTS_FILE: tensors} if shard_bytes is None else _shards(tensors, shard_bytes, file_meta)
    meta = {"format": FORMAT, "version": VERSION, "components": sorted(params), "config": config_to_dict(config),
            "storage_dtype": storage_dtype}
    extra_files = dict(extra_files or {})
    clash = sorted(set(extra_files) & (set(files) | {CONFIG_FILE}))
    if clash:
        raise ValueError(f"extra_files {clash} would overwrite the checkpoint's own files")
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{path.name}.tmp-", dir=path.parent))
    try:
        for name, part in files.items():
            save_file(part, str(tmp / name), metadata=file_meta)
        total = sum((tmp / name).stat().st_size for name in files)
        if max_total_bytes is not None and total > max_total_bytes:
            raise ValueError(f"{path}: the weights take {total} bytes, more than max_total_bytes={max_total_bytes}")
        too_big = [name for name in files if shard_bytes is not None and (tmp / name).stat().st_size > shard_bytes]
        if too_big:  # _shards leaves room for the header: a bug, never a silently oversized file
            raise AssertionError(f"{path}: shards {too_big} exceed shard_bytes={shard_bytes}")
        (tmp / CONFIG_FILE).write_text(json.dumps(meta, indent=1))
        for name, text in extra_files.items():
            (tmp / name).write_text(text)
        for name in (*files, CONFIG_FILE, *extra_files):
            with open(tmp / name, "rb") as f:
                os.fsync(f.fileno())
        if path.exists():
            old = pathlib.Path(tempfile.mkdtemp(prefix=f".{path.name}.old-", dir=path.parent))
            os.replace(path, old / path.name)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp)
    return path


def _header_bound(tensors: dict[str, np.ndarray], metadata: dict, shard_bytes: int) -> int:
    """An upper bound on a safetensors file's header (its 8-byte length, the JSON, its alignment padding):
    the JSON written with spaces and the widest dtype name and offsets."""
    header = {"__metadata__": metadata, **{key: {"dtype": "BF16", "shape": list(v.shape),
                                                 "data_offsets": [shard_bytes, shard_bytes]}
                                           for key, v in tensors.items()}}
    return 8 + len(json.dumps(header)) + 8


def _shards(tensors: dict[str, np.ndarray], shard_bytes: int, metadata: dict) -> dict[str, dict]:
    """{shard file name: tensors}: whole tensors packed in key order into files of at most ``shard_bytes``."""
    if not (isinstance(shard_bytes, int) and shard_bytes > 0):
        raise ValueError(f"shard_bytes must be a positive int, got {shard_bytes!r}")
    parts: list[dict[str, np.ndarray]] = [{}]
    for key in sorted(tensors):
        value = tensors[key]
        alone = {key: value}
        if value.nbytes + _header_bound(alone, metadata, shard_bytes) > shard_bytes:
            raise ValueError(f"tensor {key} ({value.nbytes} bytes) does not fit in a shard of "
                             f"shard_bytes={shard_bytes}")
        grown = {**parts[-1], key: value}
        if sum(v.nbytes for v in grown.values()) + _header_bound(grown, metadata, shard_bytes) > shard_bytes:
            parts.append(alone)
        else:
            parts[-1] = grown
    count = len(parts)
    return {SHARD_FILE.format(index=i + 1, count=count): part for i, part in enumerate(parts)}


def weight_files(path) -> list[pathlib.Path]:
    """The weight files of our checkpoint directory: ``weights.safetensors``, or every shard of one complete
    ``weights-XXXXX-of-NNNNN.safetensors`` set (ValueError naming what is missing or inconsistent)."""
    path = pathlib.Path(path)
    shards = sorted(p for p in path.glob("weights-*-of-*.safetensors") if SHARD_RE.fullmatch(p.name))
    if (path / WEIGHTS_FILE).is_file():
        if shards:
            raise ValueError(f"{path} holds both {WEIGHTS_FILE} and shards {[p.name for p in shards]}; "
                             "expected one layout")
        return [path / WEIGHTS_FILE]
    if not shards:
        raise ValueError(f"{path} has neither {WEIGHTS_FILE} nor weight shards weights-XXXXX-of-NNNNN.safetensors")
    counts = {int(SHARD_RE.fullmatch(p.name).group(2)) for p in shards}
    if len(counts) != 1:
        raise ValueError(f"{path}: shards of different sets {[p.name for p in shards]}; expected one -of-N count")
    (count,) = counts
    expected = [path / SHARD_FILE.format(index=i, count=count) for i in range(1, count + 1)]
    if shards != expected:
        missing = sorted(p.name for p in set(expected) - set(shards))
        raise ValueError(f"{path}: incomplete weight shards, missing {missing} (found {[p.name for p in shards]})")
    return shards


def read_meta(path) -> dict:
    """The parsed ``config.json`` of a checkpoint directory; a damaged file raises ValueError naming it."""
    file = pathlib.Path(path) / CONFIG_FILE
    try:
        meta = json.loads(file.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{file}: not valid JSON ({err.msg} at line {err.lineno}, column {err.colno}); "
                         "the checkpoint is damaged") from err
    if not isinstance(meta, dict):
        raise ValueError(f"{file}: expected a JSON object, got {type(meta).__name__}")
    return meta


def _without_legacy_refiner(data, where: str) -> tuple[dict, bool]:
    """(the config dict without ``vae.refiner``, whether it had that block): the legacy rule (module docstring)."""
    vae = data.get("vae") if isinstance(data, dict) else None
    if not isinstance(vae, dict) or LEGACY_REFINER not in vae:
        return data, False
    if not isinstance(vae[LEGACY_REFINER], dict):
        raise ValueError(  # noqa: TRY004  (a bad config is a ValueError throughout)
            f"{where}: config.vae.{LEGACY_REFINER} must be the deleted temporal refiner's object, "
            f"got {vae[LEGACY_REFINER]!r}")
    return {**data, "vae": {k: v for k, v in vae.items() if k != LEGACY_REFINER}}, True


def _read_config(path) -> tuple[WorldModelConfig, bool]:
    """(the config, whether it is a legacy one with the deleted refiner's block)."""
    meta = read_meta(path)
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}/{CONFIG_FILE} has format {meta.get('format')!r}; expected {FORMAT!r}")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path}/{CONFIG_FILE} has version {meta.get('version')!r}; this code reads {VERSION}")
    data, legacy = _without_legacy_refiner(meta["config"], f"{path}/{CONFIG_FILE}")
    return config_from_dict(data), legacy


def read_config(path) -> WorldModelConfig:
    """The config of our checkpoint directory (a legacy ``vae.refiner`` block dropped: module docstring)."""
    return _read_config(path)[0]


def load(path) -> tuple[WorldModelConfig, tuple]:
    """Our checkpoint -> (config, (dit, vae, image_encoder) modules)."""
    from safetensors.numpy import load_file

    path = pathlib.Path(path)
    config, legacy = _read_config(path)
    tensors = {}
    for file in weight_files(path):
        try:
            part = load_file(str(file))
        except Exception as err:  # safetensors raises its own error type, naming no file
            raise ValueError(f"{file}: not a readable safetensors file ({err}); it is truncated or corrupt") from err
        repeated = sorted(set(part) & set(tensors))
        if repeated:
            raise ValueError(f"{file}: tensors {repeated} are also in an earlier shard")
        tensors.update(part)
    if legacy:
        prefix = f"vae/{LEGACY_REFINER}/"
        dropped = sorted(k for k in tensors if k.startswith(prefix))
        tensors = {k: v for k, v in tensors.items() if not k.startswith(prefix)}
        logger.info("%s: legacy checkpoint of the deleted temporal refiner: dropped its config block vae.%s and "
                    "%d weight tensors %s*", path, LEGACY_REFINER, len(dropped), prefix)
    abstract = _abstract(config)
    expected = {f"{name}/{key}": _spec(v) for name, (_, state) in abstract.items()
                for key, v in flat_params(state).items()}
    storage = read_meta(path).get("storage_dtype")
    if storage is not None:  # half-precision storage of float32 parameters (``save(storage_dtype=...)``)
        tensors = {k: v.astype(np.float32) if v.dtype == np.dtype(storage) and expected.get(k, ((), ""))[1] == "float32"
                   else v for k, v in tensors.items()}
    check_tree(expected, {k: _spec(v) for k, v in tensors.items()}, str(path))
    modules = []
    for name, (graphdef, state) in abstract.items():
        prefix = f"{name}/"
        values = {k[len(prefix):]: jnp.asarray(v) for k, v in tensors.items() if k.startswith(prefix)}
        modules.append(_merge(graphdef, state, values))
    return config, tuple(modules)


# ---------------------------------------------------------------------------------------------
# Official: orbax StandardCheckpointer directories
# ---------------------------------------------------------------------------------------------


def _stored_specs(directory: pathlib.Path) -> dict[str, tuple]:
    """{key: (shape, dtype)} of an orbax directory, read from its metadata (an NNX state's trailing
    ``value`` path component dropped)."""
    import orbax.checkpoint as ocp

    meta = ocp.StandardCheckpointer().metadata(directory.resolve())
    specs = {}
    for key_path, leaf in jax.tree_util.tree_flatten_with_path(getattr(meta, "item_metadata", meta).tree)[0]:
        parts = [str(getattr(p, "key", getattr(p, "idx", getattr(p, "name", p)))) for p in key_path]
        key = "/".join(parts[:-1] if len(parts) > 1 and parts[-1] == "value" else parts)
        specs[key] = (tuple(int(d) for d in leaf.shape), str(leaf.dtype))
    return specs


def load_official(path, config: WorldModelConfig | None = None) -> tuple[WorldModelConfig, tuple]:
    """Official directory (``solaris.pt``, ``vae.pt``, ``clip.pt``) -> (config, modules).

    ``config`` defaults to the solaris preset; tests pass reduced configs with an official layout (VAE
    middle attention, CLIP ``proj_dim``). The three key trees are all checked before anything is
    restored and every difference is reported in one ValueError (a section per file).
    """
    path = pathlib.Path(path)
    config = config_lib.WorldModelConfig.solaris() if config is None else config
    absent = [f for f in OFFICIAL_FILES.values() if not (path / f).is_dir()]
    if absent:
        raise ValueError(f"official checkpoint {path} lacks the orbax directories {absent}")
    dirs = {name: path / filename for name, filename in OFFICIAL_FILES.items()}
    dit_graphdef, dit_state = _abstract(config)["dit"]
    dit_params = flat_params(dit_state)
    expected = {  # (official tree, prefixes of non-parameter leaves that may be present)
        "dit": ({k: _spec(v) for k, v in dit_params.items()}, ()),
        "vae": (official.official_vae_tree(config.vae, rng=False), (official.VAE_RNG_PREFIX,)),
        "image_encoder": (official.official_image_encoder_tree(config.image_encoder), ()),
    }
    errors = []
    for name, (tree, optional) in expected.items():
        try:
            official.check_tree(tree, _stored_specs(dirs[name]), str(dirs[name]), optional=optional)
        except ValueError as err:
            errors.append(str(err))
    if errors:
        raise ValueError("\n".join(errors))

    stored = official.read_official(dirs["dit"], expected["dit"][0])  # DiT tree == ours (docs/model.md §9.2-§9.3)
    dit = _merge(dit_graphdef, dit_state, {k: jnp.asarray(v, dit_params[k].dtype) for k, v in stored.items()})
    vae = official.load_official_vae(dirs["vae"], config.vae)
    encoder = official.load_official_image_encoder(dirs["image_encoder"], config.image_encoder)
    return config, (dit, vae, encoder)


def is_official(path) -> bool:
    return (pathlib.Path(path) / OFFICIAL_FILES["dit"]).is_dir()


def load_modules(path, config: WorldModelConfig | None = None) -> tuple[WorldModelConfig, tuple]:
    """Either format. ``config`` applies to official checkpoints only (ours carry their config)."""
    path = pathlib.Path(path)
    if (path / CONFIG_FILE).is_file():
        if config is not None and config != read_config(path):
            raise ValueError(f"{path} carries its own config, which differs from the one passed")
        return load(path)
    if is_official(path):
        return load_official(path, config)
    raise ValueError(f"{path} is neither our checkpoint ({CONFIG_FILE} + {WEIGHTS_FILE} or its shards) nor an "
                     f"official directory with {sorted(OFFICIAL_FILES.values())}")
