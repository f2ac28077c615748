"""Configuration of the world model: one frozen dataclass per component, nested in WorldModelConfig.

Every size the code needs is a field here or a property derived from fields in exactly one place
(tokens per frame, cache length, action window, RoPE split, ...). Presets:

- ``solaris``: the official full-size layout (docs/model.md §2.2-§2.3): 1.82 B stored DiT parameters.
- ``tiny``: our CPU default, 64x64 frames (sized from the measurements in docs/model.md §10.2).
- ``test``: a micro model for unit tests (compiles in well under a second).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

MULTIPLAYER_METHODS = ("attn", "concat")
COND_ENCODINGS = ("video", "image")
VAE_CODECS = ("wan", "linear_patch")
WARP_INTERPOLATIONS = ("linear", "cubic")  # how the camera warp samples between latent pixels (DiTConfig.warp_interp)
WARP_GEOMETRIES = ("shift", "rotation")  # how the camera warp moves the previous latent (DiTConfig.warp_geometry)


def _require(cond: bool, msg: str) -> None:
    if not cond:
        raise ValueError(msg)


# ---------------------------------------------------------------------------------------------
# Components
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DiTConfig:
    """The causal video DiT (docs/model.md §3)."""

    dim: int = 1536
    num_layers: int = 30
    num_heads: int = 12
    ffn_dim: int = 8960
    freq_dim: int = 256  # sinusoidal timestep embedding size
    patch_size: tuple[int, int, int] = (1, 2, 2)  # (frames, height, width)
    eps: float = 1e-6
    qk_norm: bool = True
    cross_attn_norm: bool = True
    window: int = 6  # sliding window in latent frames (causal modes)
    rope_theta: float = 10000.0
    multiplayer: str = "attn"  # "attn" = Solaris (joint self-attention), "concat" = players stacked in channels
    max_players: int = 2  # rows of the learned player embedding
    attention_impl: str = "xla"  # the only implementation today; model code never branches on platform
    context_norm_eps: float = 1e-5  # the two LayerNorms of img_emb (docs/model.md §3.2 step 3)
    dtype: str = "float32"  # compute dtype (bf16 is slower than f32 on our CPUs, docs/model.md §10.1)
    param_dtype: str = "float32"
    # Camera warp (ours; (0, 0) = off, the official model): the previous latent frame, its content moved by the
    # frame's camera turn times these (height, width) latent pixels per degree (``camera.shift_latents``), joins
    # the patch embedding's input; a turn then shows up in an input channel instead of having to be synthesised.
    camera_warp: tuple[float, float] = (0.0, 0.0)
    # Walk warp (ours; 0 = off): the warped previous latent is also moved by the frame's walk, at this many eye
    # heights per tick of a held movement key (``camera.walk_latents``; Minecraft's walking speed over its eye
    # height is 0.216 / 1.62 = 0.133). Needs the camera warp, whose input channels it shares.
    walk_warp: float = 0.0
    # Jump warp (ours; 0 = off): the warped previous latent's floor is also moved by the frame's height change,
    # simulated from the jump key (``camera.frame_lifts``), at this many eye heights per block (the geometric
    # value is 1 / 1.62, Minecraft's eye height). Needs the camera warp.
    jump_warp: float = 0.0
    # Previous-frame skip (ours; off = the official model): the velocity gets g(t) * (x_t - base) added, base being
    # the warped previous latent (the first-frame latent where the conditioning gives the frame) and g a
    # zero-initialised per-channel gate of the time embedding, so the DiT starts from "the frame is the
    # previous one, warped" and learns the change (docs/model.md §8.3). Needs the camera warp.
    previous_skip: bool = False
    # How the camera warp samples between latent pixels: "linear", or "cubic" (Catmull-Rom), which blurs less
    # when a rollout shifts its own frames step after step (``camera.shift_latents``; docs/model.md §8.1).
    warp_interp: str = "linear"
    # What a camera turn does to the previous latent: "shift", every cell by the same camera_warp pixels per degree,
    # or "rotation", the rotation homography of a pinhole camera whose field of view makes camera_warp the speed
    # at the view's centre (``camera.turn_source``): cells away from the centre move faster, up to ~2.5x at the
    # side edges for the engine's 102-degree-wide view, and rows bend (docs/model.md §8.1).
    warp_geometry: str = "shift"
    # Partner map (ours; 0 = off, the official model): one more conditioning channel, after the mask, this number
    # times the share of each latent cell that the other player's body covers in this player's view
    # (``partner.py``; from the recorded poses in training, dead reckoned from the start poses and the actions in a
    # rollout; docs/model.md §8.6). The scale speeds up the learning of the channel's zero-initialised row, as
    # ``ActionConfig.mouse_input_gain`` does for the mouse. Needs two players in ``attn`` layout.
    partner_map: float = 0.0

    def __post_init__(self):
        _require(self.dim % self.num_heads == 0, f"dim={self.dim} must be divisible by num_heads={self.num_heads}")
        _require(len(self.camera_warp) == 2 and all(math.isfinite(c) for c in self.camera_warp),
                 f"camera_warp must be two finite numbers (height, width latent pixels per degree), got {self.camera_warp}")
        _require(self.multiplayer == "attn" or not any(self.camera_warp),
                 f"camera_warp={self.camera_warp} needs multiplayer='attn' (one view per player)")
        _require(math.isfinite(self.walk_warp) and self.walk_warp >= 0.0,
                 f"walk_warp must be a finite number >= 0 (eye heights per tick), got {self.walk_warp}")
        _require(self.walk_warp == 0.0 or self.camera_warp_enabled,
                 f"walk_warp={self.walk_warp} moves the camera warp's input; it needs camera_warp on")
        _require(math.isfinite(self.jump_warp) and self.jump_warp >= 0.0,
                 f"jump_warp must be a finite number >= 0 (eye heights per block), got {self.jump_warp}")
        _require(self.jump_warp == 0.0 or self.camera_warp_enabled,
                 f"jump_warp={self.jump_warp} moves the camera warp's input; it needs camera_warp on")
        _require(self.warp_interp in WARP_INTERPOLATIONS,
                 f"warp_interp must be one of {WARP_INTERPOLATIONS}, got {self.warp_interp!r}")
        _require(self.warp_geometry in WARP_GEOMETRIES,
                 f"warp_geometry must be one of {WARP_GEOMETRIES}, got {self.warp_geometry!r}")
        _require(self.warp_geometry == "shift" or all(c > 0 for c in self.camera_warp),
                 f"warp_geometry={self.warp_geometry!r} reads the field of view from camera_warp; it needs both "
                 f"its (height, width) pixels per degree > 0, got {self.camera_warp}")
        _require(not self.previous_skip or self.camera_warp_enabled,
                 f"previous_skip={self.previous_skip} adds the camera warp's previous latent; it needs camera_warp on")
        _require(math.isfinite(self.partner_map) and self.partner_map >= 0.0,
                 f"partner_map must be a finite number >= 0 (the map's input scale; 0 = off), got {self.partner_map}")
        _require(self.head_dim % 2 == 0, f"head_dim={self.head_dim} must be even for RoPE")
        _require(self.multiplayer in MULTIPLAYER_METHODS,
                 f"multiplayer must be one of {MULTIPLAYER_METHODS}, got {self.multiplayer!r}")
        _require(self.window >= 1, f"window must be >= 1, got {self.window}")
        _require(all(p >= 1 for p in self.patch_size), f"patch_size must be positive, got {self.patch_size}")

    @property
    def head_dim(self) -> int:
        return self.dim // self.num_heads

    @property
    def camera_warp_enabled(self) -> bool:
        return any(c != 0.0 for c in self.camera_warp)

    @property
    def rope_split(self) -> tuple[int, int, int]:
        """Complex pairs per axis (frame, height, width): 22/21/21 for head_dim 128 (docs/model.md §3.5)."""
        pairs = self.head_dim // 2
        hw = pairs // 3
        return (pairs - 2 * hw, hw, hw)


@dataclass(frozen=True, slots=True)
class ActionConfig:
    """The per-player action module (docs/model.md §4, Matrix-Game 2.0 design)."""

    keyboard_dim: int = 23
    mouse_dim: int = 2
    keyboard_embed_dim: int = 128  # hidden_size of keyboard_embed
    mouse_hidden_dim: int = 1024
    keyboard_hidden_dim: int = 1024
    num_heads: int = 16
    windows_size: int = 3  # latent frames of actions seen by one latent frame
    rope_theta: float = 256.0
    rope_dims: tuple[int, int, int] = (8, 28, 28)  # only the first (temporal) part rotates
    num_action_blocks: int = 15  # the module runs in blocks [0, num_action_blocks)
    qk_norm: bool = True
    eps: float = 1e-6  # per-head q/k RMSNorms
    mouse_mlp_eps: float = 1e-5  # the LayerNorm closing mouse_mlp
    # Ours, not the reference's (1.0 = the official model): the mouse window is multiplied by this before it is
    # concatenated to the token features. The scaled camera lies in +-1.33 (a 10-degree turn: 0.67) while the
    # tokens reaching the module have an RMS of 1-4: in the shipped tiny model the mouse rows of mouse_mlp's
    # first kernel add an RMS of 0.07 to its pre-activations against 1-3.9 from the token rows, and under
    # Adam's per-weight step a larger input moves that share proportionally faster.
    mouse_input_gain: float = 1.0

    def __post_init__(self):
        _require(math.isfinite(self.mouse_input_gain) and self.mouse_input_gain > 0,
                 f"mouse_input_gain={self.mouse_input_gain} must be a finite number > 0")
        for name in ("mouse_hidden_dim", "keyboard_hidden_dim"):
            _require(getattr(self, name) % self.num_heads == 0,
                     f"{name}={getattr(self, name)} must be divisible by num_heads={self.num_heads}")
        _require(sum(self.rope_dims) == self.mouse_hidden_dim // self.num_heads,
                 f"sum(rope_dims)={sum(self.rope_dims)} must equal the head dim "
                 f"{self.mouse_hidden_dim // self.num_heads}")
        _require(self.keyboard_head_dim == self.head_dim,
                 f"keyboard head dim {self.keyboard_head_dim} must equal the mouse head dim {self.head_dim} "
                 f"(both branches share the temporal RoPE)")
        _require(self.rope_dims[0] % 2 == 0, f"rope_dims[0]={self.rope_dims[0]} must be even")

    @property
    def head_dim(self) -> int:
        return self.mouse_hidden_dim // self.num_heads

    @property
    def keyboard_head_dim(self) -> int:
        return self.keyboard_hidden_dim // self.num_heads

    @property
    def action_dim(self) -> int:
        return self.keyboard_dim + self.mouse_dim


DECODER_LAYOUT_FIELDS = ("decoder_base_dim", "decoder_head_upscale")


@dataclass(frozen=True, slots=True)
class VAEConfig:
    """A Wan-style causal video VAE (docs/model.md §7.1). ``temporal_downsample[i]`` says whether stage i
    halves time; the spatial factor is 2 ** (len(dim_mult) - 1)."""

    base_dim: int = 96
    z_dim: int = 16
    dim_mult: tuple[int, ...] = (1, 2, 4, 4)
    num_res_blocks: int = 2
    temporal_downsample: tuple[bool, ...] = (False, True, True)
    middle_attention: bool = True
    # Decoder stage widths are decoder_base_dim * dim_mult[i]; 0 = base_dim (the Wan/solaris layout).
    # A narrower decoder makes the streaming env step cheaper (the decoder dominates it on CPU).
    decoder_base_dim: int = 0
    # The decoder's head predicts decoder_head_upscale**2 RGB pixels per position, rearranged depth-to-space,
    # so the decoder runs log2(it) fewer (spatial-only) upsampling stages: 1 = Wan/solaris. On CPU the
    # full-resolution stage of a narrow decoder is its least efficient part (few channels per SIMD lane).
    decoder_head_upscale: int = 1
    # How the first-frame conditioning latents are encoded (conditioning.py): "video" = Wan i2v, the
    # video [first frame, gray, gray, ...] (latents 1.. see the gray frames; ~1 + 4 * 21 frames encoded
    # per start for solaris); "image" = only latent 0 carries the first frame's encoding, later
    # conditioning latents are 0 (one frame encoded per start: cheap resets and cacheable training data).
    cond_encoding: str = "video"
    # "wan": the causal convolutional VAE (Wan2.1, solaris). "linear_patch": a linear codec, no convolutions:
    # each latent position's (tf x sf x sf x 3) pixel patch <-> z_dim numbers by one matrix each way, fitted to
    # the patches' principal components by the VAE stage (docs/model.md §7.1, "Linear patch codec"); the
    # factors still come from dim_mult / temporal_downsample, the other layout fields are unused.
    codec: str = "wan"
    # "linear_patch" only: the decoder reads a (k x k) neighbourhood of latent positions (the grid's edge
    # repeated) instead of the position alone, so the block edges and the texture that the principal components
    # leave out are estimated from the neighbours; 1 = one position (the principal-component decoder). The
    # encoder, and so the latent space, does not depend on it (docs/model.md §7.1, "Linear patch codec").
    decoder_context: int = 1
    # Per-channel latent normalisation z = (mu - mean) / std; empty = identity (set after training).
    latent_mean: tuple[float, ...] = ()
    latent_std: tuple[float, ...] = ()
    dtype: str = "float32"  # compute dtype (the official weights are mostly bf16)
    param_dtype: str = "float32"

    def __post_init__(self):
        _require(len(self.temporal_downsample) == len(self.dim_mult) - 1,
                 f"temporal_downsample has {len(self.temporal_downsample)} entries, expected len(dim_mult)-1 = "
                 f"{len(self.dim_mult) - 1}")
        _require(len(self.latent_mean) in (0, self.z_dim) and len(self.latent_std) == len(self.latent_mean),
                 f"latent_mean/std must both be empty or have z_dim={self.z_dim} entries")
        _require(self.codec in VAE_CODECS, f"codec must be one of {VAE_CODECS}, got {self.codec!r}")
        k = self.decoder_context
        _require(isinstance(k, int) and k >= 1 and k % 2 == 1,
                 f"decoder_context must be an odd int >= 1, got {k!r}")
        _require(k == 1 or self.codec == "linear_patch",
                 f"decoder_context={k} needs codec 'linear_patch' (the 'wan' decoder is convolutional), "
                 f"got codec {self.codec!r}")
        _require(self.cond_encoding in COND_ENCODINGS,
                 f"cond_encoding must be one of {COND_ENCODINGS}, got {self.cond_encoding!r}")
        _require(self.decoder_base_dim >= 0, f"decoder_base_dim must be >= 0 (0 = base_dim), got {self.decoder_base_dim}")
        u = self.decoder_head_upscale
        _require(u >= 1 and u & (u - 1) == 0 and u <= self.spatial_factor,
                 f"decoder_head_upscale must be a power of 2 in [1, {self.spatial_factor}], got {u}")
        dropped = self.temporal_downsample[:self.head_upscale_stages]  # the decoder's last = the encoder's first
        _require(not any(dropped), f"decoder_head_upscale={u} would drop a temporal upsampling stage "
                                   f"(temporal_downsample={self.temporal_downsample}): only spatial-only stages can go")

    @property
    def decoder_dim(self) -> int:
        """Base width of the decoder stages: ``decoder_base_dim``, or ``base_dim`` when it is 0."""
        return self.decoder_base_dim or self.base_dim

    def decoder_layout(self) -> dict:
        """The fields that shape only the decoder (the latent space does not depend on them)."""
        return {name: getattr(self, name) for name in DECODER_LAYOUT_FIELDS}

    def with_decoder_layout(self, other: "VAEConfig") -> "VAEConfig":
        """This VAE (its encoder side and latent statistics) with ``other``'s decoder layout."""
        return dataclasses.replace(self, **other.decoder_layout())

    @property
    def head_upscale_stages(self) -> int:
        """How many of the decoder's last upsampling stages the head's depth-to-space replaces."""
        return self.decoder_head_upscale.bit_length() - 1

    @property
    def spatial_factor(self) -> int:
        return 2 ** (len(self.dim_mult) - 1)

    @property
    def temporal_factor(self) -> int:
        return 2 ** sum(self.temporal_downsample)

    def latent_frames(self, num_frames: int) -> int:
        """Latent frames F for T = 1 + temporal_factor * (F - 1) video frames (33 -> 9, 257 -> 65)."""
        tf = self.temporal_factor
        _require(num_frames >= 1 and (num_frames - 1) % tf == 0,
                 f"num_frames={num_frames} must be 1 + {tf} * k for temporal_factor {tf}")
        return 1 + (num_frames - 1) // tf

    def video_frames(self, num_latent_frames: int) -> int:
        """Video frames T = 1 + temporal_factor * (F - 1) decoded from F latent frames."""
        _require(num_latent_frames >= 1, f"num_latent_frames={num_latent_frames} must be >= 1")
        return 1 + self.temporal_factor * (num_latent_frames - 1)


@dataclass(frozen=True, slots=True)
class ImageEncoderConfig:
    """A ViT over the first frame whose tokens feed the cross-attention (docs/model.md §7.2).

    ``blocks_applied`` reproduces the official quirk: only the first block of the 32 runs.
    """

    image_size: int = 224
    patch_size: int = 14
    width: int = 1280
    num_layers: int = 32
    num_heads: int = 16
    mlp_ratio: float = 4.0
    blocks_applied: int = 1
    eps: float = 1e-5
    pixel_mean: tuple[float, float, float] = (0.48145466, 0.4578275, 0.40821073)
    pixel_std: tuple[float, float, float] = (0.26862954, 0.26130258, 0.27577711)
    # CLIP's post-LayerNorm + (width, proj_dim) projection: never run (tokens are returned un-pooled),
    # kept so the tree matches the official 632,076,800-parameter vision tower; 0 leaves them out.
    proj_dim: int = 1024
    dtype: str = "float32"
    param_dtype: str = "float32"

    def __post_init__(self):
        _require(self.image_size % self.patch_size == 0,
                 f"image_size={self.image_size} must be divisible by patch_size={self.patch_size}")
        _require(1 <= self.blocks_applied <= self.num_layers,
                 f"blocks_applied={self.blocks_applied} must be in [1, num_layers={self.num_layers}]")
        _require(self.width % self.num_heads == 0,
                 f"width={self.width} must be divisible by num_heads={self.num_heads}")

    @property
    def num_tokens(self) -> int:
        return (self.image_size // self.patch_size) ** 2 + 1  # patches + CLS

    @property
    def head_dim(self) -> int:
        return self.width // self.num_heads


@dataclass(frozen=True, slots=True)
class SamplerConfig:
    """Few-step flow-matching samplers (docs/model.md §5.3)."""

    ar_timesteps: tuple[int, ...] = (1000, 750, 500, 250)
    num_train_timesteps: int = 1000  # = flow_matching.NUM_TRAIN_TIMESTEPS (a literal: this module stays jax-free)
    bidirectional_steps: int = 10
    shift: float = 5.0  # sigma' = shift*sigma / (1 + (shift-1)*sigma) for the N-step schedule
    # Warped sampling noise (ours; ``noise_warp``, docs/model.md §5.3): the share rho of each latent frame's sampler
    # noises that is the previous frame's, moved by whole latent pixels with the camera turn (fresh in the border
    # a turn uncovers): noise = rho * moved + sqrt(1 - rho^2) * fresh. 0 = fresh noise for every frame (the
    # reference). Needs the camera warp (its pixels per degree). A rollout setting.
    noise_warp: float = 0.0
    # Still memory (ours; ``still_memory``, docs/model.md §8.5): while a player's view holds still (no key down, no
    # mouse movement, no jump under way: the warp is the identity), the camera warp's input for its next frame
    # keeps this share of the previous warp input, m * previous + (1 - m) * the newest frame, instead of the
    # newest frame alone. 0 = the newest frame always. Needs the camera warp. A rollout setting.
    still_memory: float = 0.0

    def __post_init__(self):
        _require(0.0 <= self.noise_warp <= 1.0, f"noise_warp must be in [0, 1], got {self.noise_warp}")
        _require(0.0 <= self.still_memory < 1.0, f"still_memory must be in [0, 1), got {self.still_memory}")


# ---------------------------------------------------------------------------------------------
# The whole model
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class WorldModelConfig:
    name: str
    frame_height: int
    frame_width: int
    num_players: int = 2
    dit: DiTConfig = field(default_factory=DiTConfig)
    action: ActionConfig = field(default_factory=ActionConfig)
    vae: VAEConfig = field(default_factory=VAEConfig)
    image_encoder: ImageEncoderConfig = field(default_factory=ImageEncoderConfig)
    sampler: SamplerConfig = field(default_factory=SamplerConfig)

    def __post_init__(self):
        f = self.vae.spatial_factor
        _require(self.frame_height % f == 0 and self.frame_width % f == 0,
                 f"frame size {self.frame_height}x{self.frame_width} must be divisible by the VAE factor {f}")
        _, ph, pw = self.dit.patch_size
        _require(self.latent_height % ph == 0 and self.latent_width % pw == 0,
                 f"latent size {self.latent_height}x{self.latent_width} must be divisible by patch {ph}x{pw}")
        _require(self.num_players >= 1, f"num_players must be >= 1, got {self.num_players}")
        _require(self.dit.multiplayer == "concat" or self.num_players <= self.dit.max_players,
                 f"num_players={self.num_players} exceeds dit.max_players={self.dit.max_players}")
        _require(self.action.num_action_blocks <= self.dit.num_layers,
                 f"action.num_action_blocks={self.action.num_action_blocks} > dit.num_layers={self.dit.num_layers}")
        _require(self.sampler.noise_warp == 0.0 or self.dit.camera_warp_enabled,
                 f"sampler.noise_warp={self.sampler.noise_warp} moves the noise by the camera warp's pixels per "
                 f"degree; it needs dit.camera_warp on")
        _require(not self.dit.partner_map or (self.num_players == 2 and self.dit.multiplayer == "attn"),
                 f"dit.partner_map maps each player's view of the other: it needs num_players=2 and multiplayer="
                 f"'attn', got {self.num_players} and {self.dit.multiplayer!r}")
        _require(self.sampler.still_memory == 0.0 or self.dit.camera_warp_enabled,
                 f"sampler.still_memory={self.sampler.still_memory} blends the camera warp's input; it needs "
                 f"dit.camera_warp on")

    # -- derived sizes (the only place they are computed) --------------------------------------
    @property
    def latent_height(self) -> int:
        return self.frame_height // self.vae.spatial_factor

    @property
    def latent_width(self) -> int:
        return self.frame_width // self.vae.spatial_factor

    @property
    def latent_channels(self) -> int:
        return self.vae.z_dim

    @property
    def frames_per_step(self) -> int:
        """Video frames per latent frame (the env's k)."""
        return self.vae.temporal_factor

    @property
    def mask_channels(self) -> int:
        return self.frames_per_step

    @property
    def stream_players(self) -> int:
        """Players on the DiT's player axis: P for ``attn``, 1 for ``concat`` (players in channels)."""
        return 1 if self.dit.multiplayer == "concat" else self.num_players

    @property
    def players_in_channels(self) -> int:
        return self.num_players if self.dit.multiplayer == "concat" else 1

    @property
    def partner_channels(self) -> int:
        """Conditioning channels of the partner map (``DiTConfig.partner_map``): 1 or 0."""
        return int(self.dit.partner_map > 0)

    @property
    def in_channels(self) -> int:
        """Patch-embed input: noisy latent + cond = [mask, partner map (``partner_channels``), first-frame latent]
        (36 for solaris)."""
        c = self.players_in_channels
        return c * (2 * self.latent_channels + self.mask_channels + self.partner_channels)

    @property
    def patch_in_channels(self) -> int:
        """The patch embedding's input channels: ``in_channels``, plus the warped previous latent with
        ``DiTConfig.camera_warp``."""
        return self.in_channels + (self.out_channels if self.dit.camera_warp_enabled else 0)

    @property
    def out_channels(self) -> int:
        return self.players_in_channels * self.latent_channels

    @property
    def tokens_per_frame(self) -> int:
        """Tokens per latent frame per stream player (880 for solaris)."""
        _, ph, pw = self.dit.patch_size
        return (self.latent_height // ph) * (self.latent_width // pw)

    @property
    def cache_tokens(self) -> int:
        """Self-attention KV cache length: window x players x tokens (10560 for solaris)."""
        return self.dit.window * self.stream_players * self.tokens_per_frame

    @property
    def action_window(self) -> int:
        """Actions seen by one latent frame (12 for solaris)."""
        return self.action.windows_size * self.frames_per_step

    @property
    def action_left_padding(self) -> int:
        """Left padding so the action of frame k*i is the last one latent frame i sees (11 for solaris)."""
        return self.action_window - 1

    @property
    def mouse_in_dim(self) -> int:
        """mouse_mlp input: the window's mouse values plus the token features (1560 for solaris)."""
        return self.players_in_channels * self.action.mouse_dim * self.action_window + self.dit.dim

    @property
    def keyboard_in_dim(self) -> int:
        return self.players_in_channels * self.action.keyboard_dim

    @property
    def context_width(self) -> int:
        """Width of the image-encoder tokens the DiT cross-attends to (1280 for solaris, x P for concat)."""
        return self.players_in_channels * self.image_encoder.width

    def replace(self, **kw) -> "WorldModelConfig":
        return dataclasses.replace(self, **kw)

    # -- presets ----------------------------------------------------------------------------------
    @classmethod
    def solaris(cls, **override) -> "WorldModelConfig":
        """The official layout: 352x640 frames -> 44x80x16 latents, 880 tokens/player/frame.
        1,824,481,856 stored DiT parameters (1,619,281,856 active)."""
        wan_mean = (-0.7571, -0.7089, -0.9113, 0.1075, -0.1745, 0.9653, -0.1517, 1.5508, 0.4134, -0.0715,
                    0.5517, -0.3632, -0.1922, -0.9497, 0.2503, -0.2921)
        wan_std = (2.8184, 1.4541, 2.3275, 2.6558, 1.2196, 1.7708, 2.6052, 2.0743, 3.2687, 2.1526, 2.8652,
                   1.5579, 1.6382, 1.1253, 2.8251, 1.9160)
        kw = dict(name="solaris", frame_height=352, frame_width=640, vae=VAEConfig(latent_mean=wan_mean,
                                                                                    latent_std=wan_std))
        return cls(**{**kw, **override})

    @classmethod
    def tiny(cls, **override) -> "WorldModelConfig":
        """CPU default: 64x64 frames -> 8x8x16 latents, patch 2 -> 16 tokens/player/frame, d=256, 8 layers.
        docs/model.md §10.2: d256/L8 with 16 tokens trains at ~1.4 s/step (B=8, 8 latent frames, P=2) on 2 cores,
        ~2x faster than patch 1 (64 tokens) at the same width, which leaves room for stage 4.
        VAE: the decoder dominates an env step (benchmarks/model_step.py). Measured decode_step of one
        latent frame for 2 players (8 frames of 64x64): base 32 / mult (1,2,2,4) 16.8 GFLOP, 130 ms;
        base 16 / mult (1,2,4,4) 5.3 GFLOP, 47 ms (2.5 M params); base 12 / (1,2,4,8) 3.4 GFLOP. Encoder base 16 /
        (1,2,4,4); decoder (decoder_base_dim) with the same mult: 16 -> 5.25 GFLOP, 49 ms; 12 -> 2.98 GFLOP, 38 ms;
        8 -> 1.35 GFLOP, 19 ms (0.39 M decoder params). Its 64x64 stage (8 channels) was half of that time,
        so the head predicts 2x2 pixels from the 32x32 stage instead (decoder_head_upscale=2: 0.85 GFLOP,
        9 ms, same parameter count) -- chosen, to fit the 20 env steps/s budget."""
        kw = dict(
            name="tiny", frame_height=64, frame_width=64,
            # camera_warp: the previous latent moved by the frame's turn as an input (session 13: 64x64 frames turn
            # ~0.80 / 0.45 px per degree of pitch / yaw; /8 for the latent grid)
            dit=DiTConfig(dim=256, num_layers=8, num_heads=4, ffn_dim=1024, window=6, camera_warp=(0.0998, 0.0561)),
            # mouse_input_gain 10: on the synthetic shift task (benchmarks/action_learnability.py, from scratch) the
            # DiT reads the turn's direction sooner than with 1 (action_gain at 300 / 600 steps 2.7 / 12.4 % vs
            # 0.7 / 6.5 %)
            action=ActionConfig(keyboard_embed_dim=64, mouse_hidden_dim=256, keyboard_hidden_dim=256, num_heads=4,
                                rope_dims=(8, 28, 28), num_action_blocks=4, mouse_input_gain=10.0),
            vae=VAEConfig(base_dim=16, z_dim=16, dim_mult=(1, 2, 4, 4), num_res_blocks=1,
                          temporal_downsample=(False, True, True), middle_attention=False, decoder_base_dim=8,
                          decoder_head_upscale=2, cond_encoding="image"),
            image_encoder=ImageEncoderConfig(image_size=64, patch_size=8, width=128, num_layers=2, num_heads=4,
                                             blocks_applied=2, proj_dim=0),
        )
        return cls(**{**kw, **override})

    @classmethod
    def tiny16(cls, **override) -> "WorldModelConfig":
        """``tiny`` with 4x spatial compression: 64x64 frames -> 16x16x16 latents, patch 4 -> the same 16
        tokens/player/frame, so the DiT costs what ``tiny``'s does. The latent holds 4x the numbers of ``tiny``'s,
        for the partner (2-3 pixels wide far away), the hotbar and block edges (docs/model.md §10.3;
        ``benchmarks/autoencoder_capacity.py``: 21.2 dB against 18.7 for 8x8x16 after the same 150 updates).
        Measured with random weights, dream env B = 1 on 2 CPU cores: 0.93x ``tiny``'s steps/s (d = 384: 0.56x,
        patch 2 with 64 tokens: 0.28x). The camera warp's latent pixels per degree double with the grid. The walk warp
        (0.1 eye heights per tick, the best fit on the engine's walking frames) gives a model trained from scratch
        the walk as an input (docs/model.md §8.1; session 31: fine-tuned with it, the shipped weights zoomed in
        when walking forward and followed back and strafe right, which they ignored without it)."""
        base = cls.tiny()
        kw = dict(
            name="tiny16",
            dit=dataclasses.replace(base.dit, patch_size=(1, 4, 4), camera_warp=(0.1996, 0.1122), walk_warp=0.1),
            vae=dataclasses.replace(base.vae, dim_mult=(1, 2, 4), temporal_downsample=(True, True),
                                    decoder_head_upscale=1, codec="linear_patch"),
        )
        return base.replace(**{**kw, **override})

    @classmethod
    def test(cls, **override) -> "WorldModelConfig":
        """Micro model for unit tests: 32x32 frames, d=64, 2 layers, window 2."""
        kw = dict(
            name="test", frame_height=32, frame_width=32,
            dit=DiTConfig(dim=64, num_layers=2, num_heads=2, ffn_dim=128, freq_dim=32, window=2),
            action=ActionConfig(keyboard_embed_dim=16, mouse_hidden_dim=64, keyboard_hidden_dim=64, num_heads=2,
                                rope_dims=(8, 12, 12), num_action_blocks=1),
            vae=VAEConfig(base_dim=8, z_dim=4, dim_mult=(1, 2, 2, 2), num_res_blocks=1,
                          temporal_downsample=(False, True, True), middle_attention=False),
            image_encoder=ImageEncoderConfig(image_size=32, patch_size=8, width=32, num_layers=1, num_heads=2,
                                             blocks_applied=1, proj_dim=0),
        )
        return cls(**{**kw, **override})


PRESETS = {"solaris": WorldModelConfig.solaris, "tiny": WorldModelConfig.tiny, "tiny16": WorldModelConfig.tiny16,
           "test": WorldModelConfig.test}


def preset(name: str, **override) -> WorldModelConfig:
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
    return PRESETS[name](**override)
