"""The official VAE and CLIP checkpoints (``vae.pt``, ``clip.pt``; docs/model.md §9.2-§9.3) <-> our modules.

Both are orbax ``StandardCheckpointer`` directories holding the NNX state of the reference modules
(``WanVAE_`` and ``CLIPModel`` of solaris-wm/solaris@0be45a8, built by ``model_loaders.py``). Their key
trees for the solaris preset are ``tests/solaris_env/world_model/fixtures/{vae,clip}-param-tree.txt``. Our
``CausalVideoVAE`` / ``ImageEncoder`` hold the same numbers under other names and a few other shapes;
this module is the pure key mapping between the two layouts, plus loaders and a writer.

VAE (ours -> official; every conv kernel is (kt, kh, kw, in, out) or (kh, kw, in, out) in both):

- ``encoder/conv_in`` -> ``encoder/conv1``; ``decoder/conv_in`` -> ``decoder/conv1``;
  ``encoder/down/i`` -> ``encoder/downsamples/i``; ``decoder/up/i`` -> ``decoder/upsamples/i`` (same
  indices: stage ResBlocks then the resample layer); ``middle/i`` and the top-level ``conv1``/``conv2``
  keep their names.
- ResBlock: the reference keeps ``residual = [norm, silu, conv, norm, silu, dropout, conv]`` as a list, so
  ``norm1`` -> ``residual/0``, ``conv1`` -> ``residual/2``, ``norm2`` -> ``residual/3``,
  ``conv2`` -> ``residual/6``; ``shortcut`` keeps its name.
- Head: ``head = [norm, silu, conv]``, so ``head/norm`` -> ``head/0``, ``head/conv`` -> ``head/2``.
- RMSNorm ``gamma`` (C,) -> (C, 1, 1, 1) (ResBlocks, heads) or (C, 1, 1) (the attention's norm).
- Middle attention: the reference's ``to_qkv``/``proj`` are 1x1 ``nnx.Conv``: kernel (C, n) -> (1, 1, C, n).
  The reference always has the middle attention, so ``middle_attention=False`` has no official layout.
- Down/upsample ``conv``/``time_conv`` keep their names and shapes.
- Dtypes as the reference creates them: gammas f32; ``encoder/head/2``, ``decoder/conv1``,
  ``decoder/head/2`` and the 3x3 conv of the temporal upsamplers f32; every other kernel/bias bf16.
  Loading casts to our ``param_dtype`` (lossless into f32).
- Not a parameter: every reference ``Dropout`` shares one ``Rngs``, whose state is stored once under
  ``decoder/middle/0/residual/5/rngs/default/{count,key}`` (``()`` uint32 and a key, which orbax writes as
  raw key data, uint32 (2,)). Loading accepts these two leaves or their absence and ignores them.

CLIP vision tower (ours -> official; all f32, kernels (in, out), patch kernel (p, p, 3, width) in both):
``X`` -> ``model/X`` with ``patch_embed`` -> ``patch_embedding``, ``blocks/i`` -> ``transformer/i``,
``blocks/i/fc1`` -> ``transformer/i/mlp/layers/0``, ``fc2`` -> ``mlp/layers/2``; ``cls_embedding`` (D,) ->
(1, 1, D) and ``pos_embedding`` (L, D) -> (1, L, D); the fused qkv column layout (3, heads, head_dim) is
the same. The reference always has ``post_norm`` and ``head``, so ``proj_dim=0`` has no official layout.

Numerics (not a layout matter, noted for parity work): the reference runs its RMS_norm normalisation and
most VAE convs in bf16; ours compute in ``cfg.dtype``.

Flat trees here are ``{'a/b/c': array}`` with list indices as path components. On disk every leaf of an
NNX state gains a trailing ``value`` component; both that layout and a plain one are read.
"""

from __future__ import annotations

import pathlib
from typing import Callable

import jax
import jax.numpy as jnp
from flax import nnx

from solaris_env.world_model.config import ImageEncoderConfig, VAEConfig, WorldModelConfig
from solaris_env.world_model.image_encoder import ImageEncoder
from solaris_env.world_model.vae import CausalVideoVAE

Spec = tuple[tuple[int, ...], str]  # (shape, dtype name)

_F32, _BF16 = "float32", "bfloat16"
_RESBLOCK = {"norm1": "residual/0", "conv1": "residual/2", "norm2": "residual/3", "conv2": "residual/6",
             "shortcut": "shortcut"}
_HEAD = {"norm": "0", "conv": "2"}
VAE_RNG_PREFIX = "decoder/middle/0/residual/5/rngs/default/"
VAE_RNG_LEAVES = {VAE_RNG_PREFIX + "count": ((), "uint32"), VAE_RNG_PREFIX + "key": ((), "key<fry>")}


# ---------------------------------------------------------------------------------------------
# Leaf mappings: our key -> (official key, official shape, official dtype)
# ---------------------------------------------------------------------------------------------


def flat_params(module) -> dict[str, jax.Array]:
    """{'a/b/c': value} of a (possibly abstract) module's parameters."""
    return {"/".join(map(str, path)): v.get_value() if isinstance(v, nnx.Variable) else v
            for path, v in nnx.to_flat_state(nnx.state(module, nnx.Param))}


def _abstract_vae(cfg: VAEConfig):
    return nnx.eval_shape(lambda: CausalVideoVAE(cfg, rngs=nnx.Rngs(0)))


def _abstract_image_encoder(cfg: ImageEncoderConfig):
    return nnx.eval_shape(lambda: ImageEncoder(cfg, rngs=nnx.Rngs(0)))


def _vae_leaf(key: str, shape: tuple[int, ...], has_time_conv: Callable[[str], bool]) -> tuple[str, tuple, str]:
    """One of our VAE leaves -> (official key, official shape, official dtype)."""
    parts = key.split("/")
    if parts[0] in ("conv1", "conv2"):  # top-level moment / latent 1x1x1 convs
        return key, shape, _BF16
    net, rest = parts[0], parts[1:]  # 'encoder' | 'decoder'
    if rest[0] == "conv_in":
        return "/".join([net, "conv1", *rest[1:]]), shape, _F32 if net == "decoder" else _BF16
    if rest[0] == "head":
        out = "/".join([net, "head", _HEAD[rest[1]], *rest[2:]])
        if rest[1] == "norm":
            return out, (*shape, 1, 1, 1), _F32
        return out, shape, _F32
    lists = {"down": "downsamples", "up": "upsamples", "middle": "middle"}
    if rest[0] not in lists or len(rest) < 4:
        raise ValueError(f"VAE leaf {key!r} has no official counterpart")
    prefix, layer, leaf = f"{net}/{lists[rest[0]]}/{rest[1]}", rest[2], rest[3:]
    if layer in _RESBLOCK:  # ResBlock
        out = "/".join([prefix, _RESBLOCK[layer], *leaf])
        return (out, (*shape, 1, 1, 1), _F32) if layer.startswith("norm") else (out, shape, _BF16)
    if layer == "norm":  # the middle attention's RMSNorm (images=True: gamma (C, 1, 1))
        return "/".join([prefix, "norm", *leaf]), (*shape, 1, 1), _F32
    if layer in ("to_qkv", "proj"):  # 1x1 nnx.Conv in the reference
        return "/".join([prefix, layer, *leaf]), ((1, 1, *shape) if leaf == ["kernel"] else shape), _BF16
    if layer == "time_conv":
        return "/".join([prefix, layer, *leaf]), shape, _BF16
    if layer == "conv":  # resample 3x3 conv; f32 only in the temporal upsamplers (created without dtype)
        f32 = rest[0] == "up" and has_time_conv(f"{net}/{rest[0]}/{rest[1]}")
        return "/".join([prefix, layer, *leaf]), shape, _F32 if f32 else _BF16
    raise ValueError(f"VAE leaf {key!r} has no official counterpart")


def _check_official_vae_cfg(cfg: VAEConfig) -> None:
    if not cfg.middle_attention:
        raise ValueError("the official VAE layout always has the middle attention block; "
                         "a VAEConfig with middle_attention=False cannot be converted")


def _check_official_clip_cfg(cfg: ImageEncoderConfig) -> None:
    if not cfg.proj_dim:
        raise ValueError("the official CLIP layout always has post_norm and head; "
                         "an ImageEncoderConfig with proj_dim=0 cannot be converted")


def vae_leaf_map(cfg: VAEConfig) -> dict[str, tuple[str, tuple, str]]:
    """{our key: (official key, official shape, official dtype)} for every parameter of our VAE."""
    _check_official_vae_cfg(cfg)
    ours = flat_params(_abstract_vae(cfg))
    layers_with_time_conv = {k.rsplit("/time_conv/", 1)[0] for k in ours if "/time_conv/" in k}
    return {k: _vae_leaf(k, tuple(v.shape), layers_with_time_conv.__contains__) for k, v in ours.items()}


def _clip_leaf(key: str, shape: tuple[int, ...]) -> tuple[str, tuple, str]:
    parts = key.split("/")
    if parts[0] == "patch_embed":
        parts[0] = "patch_embedding"
    elif parts[0] == "cls_embedding":
        shape = (1, 1, *shape)
    elif parts[0] == "pos_embedding":
        shape = (1, *shape)
    elif parts[0] == "blocks":
        parts[0] = "transformer"
        fc = {"fc1": ["mlp", "layers", "0"], "fc2": ["mlp", "layers", "2"]}
        if parts[2] in fc:
            parts = parts[:2] + fc[parts[2]] + parts[3:]
    elif parts[0] not in ("pre_norm", "post_norm", "head"):
        raise ValueError(f"image-encoder leaf {key!r} has no official counterpart")
    return "/".join(["model", *parts]), shape, _F32


def image_encoder_leaf_map(cfg: ImageEncoderConfig) -> dict[str, tuple[str, tuple, str]]:
    """{our key: (official key, official shape, official dtype)} for every parameter of our ImageEncoder."""
    _check_official_clip_cfg(cfg)
    return {k: _clip_leaf(k, tuple(v.shape)) for k, v in flat_params(_abstract_image_encoder(cfg)).items()}


def official_vae_tree(cfg: VAEConfig, *, rng: bool = True) -> dict[str, Spec]:
    """{official key: (shape, dtype)}: the reference ``WanVAE_`` NNX state for ``cfg`` (with ``rng``, also
    the two non-parameter Rngs leaves as the state holds them: ``()`` uint32 and ``()`` key<fry>)."""
    tree = {o: (s, d) for o, s, d in vae_leaf_map(cfg).values()}
    return {**tree, **VAE_RNG_LEAVES} if rng else tree


def official_image_encoder_tree(cfg: ImageEncoderConfig) -> dict[str, Spec]:
    """{official key: (shape, dtype)}: the reference ``CLIPModel`` NNX state for ``cfg``."""
    return {o: (s, d) for o, s, d in image_encoder_leaf_map(cfg).values()}


# ---------------------------------------------------------------------------------------------
# Converters between flat trees
# ---------------------------------------------------------------------------------------------


def _to_official(flat: dict[str, jax.Array], leaf_map: dict, official_dtypes: bool) -> dict[str, jax.Array]:
    missing, unexpected = sorted(set(leaf_map) - set(flat)), sorted(set(flat) - set(leaf_map))
    if missing or unexpected:
        raise ValueError(f"state does not match the config: missing {missing}, unexpected {unexpected}")
    out = {}
    for key, (okey, oshape, odtype) in leaf_map.items():
        v = jnp.reshape(flat[key], oshape)
        out[okey] = v.astype(odtype) if official_dtypes else v
    return out


def _from_official(flat: dict[str, jax.Array], leaf_map: dict, ours: dict[str, jax.Array],
                   where: str) -> dict[str, jax.Array]:
    expected = {okey: (oshape, odtype) for okey, oshape, odtype in leaf_map.values()}
    check_tree(expected, {k: _spec(v) for k, v in flat.items()}, where)
    return {key: jnp.reshape(flat[okey], ours[key].shape).astype(ours[key].dtype)
            for key, (okey, _, _) in leaf_map.items()}


def to_official_vae(vae: CausalVideoVAE, *, official_dtypes: bool = True, rng: bool = True) -> dict[str, jax.Array]:
    """Our VAE -> the flat official state (reference names, shapes and, with ``official_dtypes``, dtypes:
    mostly bf16, so f32 weights are rounded). ``rng`` adds the Rngs leaves as orbax writes them."""
    out = _to_official(flat_params(vae), vae_leaf_map(vae.cfg), official_dtypes)
    if rng:
        out[VAE_RNG_PREFIX + "count"] = jnp.zeros((), jnp.uint32)
        out[VAE_RNG_PREFIX + "key"] = jax.random.key_data(jax.random.key(0))
    return out


def from_official_vae(flat: dict[str, jax.Array], cfg: VAEConfig) -> CausalVideoVAE:
    """Flat official state (the Rngs leaves optional, ignored) -> our VAE, params cast to ``cfg.param_dtype``."""
    flat = {k: v for k, v in flat.items() if not k.startswith(VAE_RNG_PREFIX)}
    abstract = _abstract_vae(cfg)
    values = _from_official(flat, vae_leaf_map(cfg), flat_params(abstract), "official VAE")
    return _merge(abstract, values)


def to_official_image_encoder(encoder: ImageEncoder, *, official_dtypes: bool = True) -> dict[str, jax.Array]:
    """Our ImageEncoder -> the flat official CLIP state."""
    return _to_official(flat_params(encoder), image_encoder_leaf_map(encoder.cfg), official_dtypes)


def from_official_image_encoder(flat: dict[str, jax.Array], cfg: ImageEncoderConfig) -> ImageEncoder:
    """Flat official CLIP state -> our ImageEncoder, params cast to ``cfg.param_dtype``."""
    abstract = _abstract_image_encoder(cfg)
    values = _from_official(flat, image_encoder_leaf_map(cfg), flat_params(abstract), "official CLIP")
    return _merge(abstract, values)


def _merge(abstract, values: dict[str, jax.Array]):
    graphdef, state = nnx.split(abstract)
    flat = [(path, values["/".join(map(str, path))]) for path, _ in nnx.to_flat_state(state)]
    return nnx.merge(graphdef, nnx.from_flat_state(flat))


# ---------------------------------------------------------------------------------------------
# The one strict check
# ---------------------------------------------------------------------------------------------


def _spec(a) -> Spec:
    return tuple(int(d) for d in a.shape), str(a.dtype)


def check_tree(expected: dict[str, Spec], found: dict[str, Spec], where: str, *, check_dtype: bool = False,
               optional: tuple[str, ...] = (), against: str = "the official layout for this config") -> None:
    """Raise ONE ValueError listing missing, unexpected and mis-shaped (with ``check_dtype`` also mis-typed)
    keys of ``found`` against ``expected``; keys starting with an ``optional`` prefix are ignored."""
    found = {k: v for k, v in found.items() if not k.startswith(optional)} if optional else found
    missing, unexpected = sorted(set(expected) - set(found)), sorted(set(found) - set(expected))
    wrong = [f"{k}: expected {tuple(expected[k][0])} {expected[k][1]}, found {tuple(found[k][0])} {found[k][1]}"
             for k in sorted(set(expected) & set(found))
             if tuple(expected[k][0]) != tuple(found[k][0]) or (check_dtype and expected[k][1] != found[k][1])]
    if missing or unexpected or wrong:
        lines = [f"{where} does not match {against}:"]
        lines += [f"  missing keys ({len(missing)}): {missing}"] if missing else []
        lines += [f"  unexpected keys ({len(unexpected)}): {unexpected}"] if unexpected else []
        lines += ([f"  mis-shaped keys ({len(wrong)}):"] + [f"    {w}" for w in wrong]) if wrong else []
        raise ValueError("\n".join(lines))


# ---------------------------------------------------------------------------------------------
# Orbax directories
# ---------------------------------------------------------------------------------------------


def _key_str(entry) -> str:
    return str(getattr(entry, "key", getattr(entry, "idx", getattr(entry, "name", entry))))


def _strip_value(parts: list[str]) -> str:
    """A stored leaf path -> our flat key: an NNX state leaf's trailing ``value`` component is dropped."""
    return "/".join(parts[:-1] if len(parts) > 1 and parts[-1] == "value" else parts)


def _unflatten(flat: dict[str, object], suffix: tuple[str, ...] = ()) -> dict:
    tree: dict = {}
    for key, leaf in flat.items():
        node = tree
        *parents, last = key.split("/") + list(suffix)
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = leaf
    return tree


def save_official(path, flat: dict[str, jax.Array], *, value_suffix: bool = True) -> pathlib.Path:
    """Write a flat official state as an orbax ``StandardCheckpointer`` directory (what the reference's
    save of an NNX state produces: with ``value_suffix`` every leaf path ends in ``value``). Tests use it
    to write official-layout checkpoints from our modules."""
    import orbax.checkpoint as ocp

    path = pathlib.Path(path).resolve()
    checkpointer = ocp.StandardCheckpointer()
    checkpointer.save(path, _unflatten(flat, ("value",) if value_suffix else ()))
    checkpointer.wait_until_finished()
    return path


def read_official(path, expected: dict[str, Spec], *, optional: tuple[str, ...] = ()) -> dict[str, jax.Array]:
    """Restore an orbax directory whose leaves (a trailing ``value`` stripped) must be exactly ``expected``
    by key and shape (leaves under an ``optional`` prefix may be present too). Returns {key: array} in the
    stored dtypes. Nothing is unpickled: orbax reads its own metadata and tensorstore arrays."""
    import orbax.checkpoint as ocp

    path = pathlib.Path(path).resolve()
    if not path.is_dir():
        raise ValueError(f"official checkpoint {path} is not an orbax directory")
    checkpointer = ocp.StandardCheckpointer()
    meta = checkpointer.metadata(path)
    tree = getattr(meta, "item_metadata", meta).tree
    stored = {_strip_value([_key_str(p) for p in kp]): m for kp, m in jax.tree_util.tree_flatten_with_path(tree)[0]}
    check_tree(expected, {k: (tuple(m.shape), str(m.dtype)) for k, m in stored.items()}, str(path), optional=optional)
    # The abstract target: the expected official layout (its shapes, the stored dtypes) nested like the
    # stored tree; optional leaves are restored as stored and then dropped.
    def abstract(key_path, m):
        key = _strip_value([_key_str(p) for p in key_path])
        return jax.ShapeDtypeStruct(tuple(expected[key][0]) if key in expected else tuple(m.shape), m.dtype)

    restored = checkpointer.restore(path, jax.tree_util.tree_map_with_path(abstract, tree))
    out = {}
    for key_path, value in jax.tree_util.tree_flatten_with_path(restored)[0]:
        key = _strip_value([_key_str(p) for p in key_path])
        if key in expected:
            out[key] = value
    return out


def _vae_cfg(cfg) -> VAEConfig:
    return WorldModelConfig.solaris().vae if cfg is None else getattr(cfg, "vae", cfg)


def _clip_cfg(cfg) -> ImageEncoderConfig:
    return WorldModelConfig.solaris().image_encoder if cfg is None else getattr(cfg, "image_encoder", cfg)


def load_official_vae(path, cfg: VAEConfig | WorldModelConfig | None = None) -> CausalVideoVAE:
    """``vae.pt`` (an orbax directory) -> our ``CausalVideoVAE`` (default: the solaris preset's VAE).

    Strict: one ValueError lists every missing, unexpected and mis-shaped key against the official tree."""
    cfg = _vae_cfg(cfg)
    flat = read_official(path, official_vae_tree(cfg, rng=False), optional=(VAE_RNG_PREFIX,))
    return from_official_vae(flat, cfg)


def load_official_image_encoder(path, cfg: ImageEncoderConfig | WorldModelConfig | None = None) -> ImageEncoder:
    """``clip.pt`` (an orbax directory) -> our ``ImageEncoder`` (default: the solaris preset's encoder)."""
    cfg = _clip_cfg(cfg)
    flat = read_official(path, official_image_encoder_tree(cfg))
    return from_official_image_encoder(flat, cfg)
