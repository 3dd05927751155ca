"""The paper's Refiner backbone: SD-Turbo (diffusers AutoencoderKL + UNet2DConditionModel), one step, as in
Difix / pix2pix-turbo, built from a local SD-Turbo folder (nothing is downloaded).

What it takes from them, the prompt embedding and what trains: docs/design.md, "Refiner: the SD-Turbo
backbone".
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
import torch
from torch import nn

from trioman.toolkit.refiner.config import RefinerConfig
from trioman.toolkit.refiner.model import INPUT_NAMES, check_refiner_inputs, view_images

PROMPT = "remove degradation"  # Difix's fixed prompt
PROMPT_FILE = "prompt_embeds.safetensors"
TIMESTEP = 199  # Difix's training and inference timestep (pix2pix-turbo: 999)
SKIP_INIT = 1e-5  # pix2pix-turbo's constant initial weight of the skip convs
WEIGHT_NAMES = ("diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.bin")


class SdTurboFolderError(FileNotFoundError):
    """A part of the local SD-Turbo folder is missing or unreadable (one line naming it)."""


def _require(path: Path, what: str) -> Path:
    if not path.exists():
        raise SdTurboFolderError(f"{path}: missing ({what}); the sd-turbo backbone reads a local diffusers folder, nothing is downloaded")
    return path


def check_folder(root: str | Path) -> Path:
    """Raise SdTurboFolderError naming the first missing part of a diffusers-layout folder: model_index.json,
    vae/ and unet/ (config.json and weights), scheduler/scheduler_config.json, the prompt embedding."""
    root = Path(root)
    if not root.is_dir():
        raise SdTurboFolderError(f"{root}: not a folder (pretrained_path: a local SD-Turbo folder in diffusers layout)")
    _require(root / "model_index.json", "the pipeline index of a diffusers folder")
    for part in ("vae", "unet"):
        _require(root / part, f"the {'AutoencoderKL' if part == 'vae' else 'UNet2DConditionModel'} folder")
        _require(root / part / "config.json", f"the {part} config")
        if not any((root / part / n).is_file() for n in WEIGHT_NAMES):
            raise SdTurboFolderError(f"{root / part / WEIGHT_NAMES[0]}: missing (the {part} weights; {WEIGHT_NAMES[1]} also accepted)")
    _require(root / "scheduler" / "scheduler_config.json", "the DDPM scheduler config")
    if not (root / PROMPT_FILE).is_file():
        for part in ("tokenizer", "text_encoder"):
            _require(root / part, f"{PROMPT_FILE} is absent, so the prompt embedding is computed from tokenizer/ and text_encoder/")
        if importlib.util.find_spec("transformers") is None:
            raise SdTurboFolderError(f"{root / PROMPT_FILE}: missing, and computing it from text_encoder/ needs the transformers package")
    return root


def load_prompt_embedding(root: Path) -> torch.Tensor:
    """The prompt embedding [1, L, D] of ``PROMPT``: DIR/prompt_embeds.safetensors, else CLIP's last hidden state."""
    path = root / PROMPT_FILE
    if path.is_file():
        from safetensors.torch import load_file

        tensors = load_file(str(path))
        if "prompt_embeds" not in tensors:
            raise SdTurboFolderError(f"{path}: no tensor 'prompt_embeds' (found {sorted(tensors)})")
        embeds = tensors["prompt_embeds"].float()
    else:
        from transformers import CLIPTextModel, CLIPTokenizer

        tokenizer = CLIPTokenizer.from_pretrained(str(root / "tokenizer"), local_files_only=True)
        encoder = CLIPTextModel.from_pretrained(str(root / "text_encoder"), local_files_only=True).eval()
        ids = tokenizer(PROMPT, padding="max_length", max_length=tokenizer.model_max_length, truncation=True, return_tensors="pt").input_ids
        with torch.no_grad():
            embeds = encoder(ids)[0].float()
    if embeds.ndim == 2:
        embeds = embeds[None]
    if embeds.ndim != 3 or embeds.shape[0] != 1:
        raise SdTurboFolderError(f"{path}: prompt_embeds must be [1, L, D], got {tuple(embeds.shape)}")
    return embeds


def save_prompt_embedding(embeds: torch.Tensor, root: str | Path) -> Path:
    """Write ``embeds`` [1, L, D] as DIR/prompt_embeds.safetensors (so inference never needs the text encoder)."""
    from safetensors.torch import save_file

    path = Path(root) / PROMPT_FILE
    save_file({"prompt_embeds": embeds.detach().float().contiguous()}, str(path))
    return path


def _span_views(attn: nn.Module, views: int) -> None:
    """Make self-attention module ``attn`` attend over the V views jointly: [(B V), n, d] -> [B, (V n), d] in,
    back out. Hooks, so the parameter names stay the diffusers ones."""

    def before(module: nn.Module, args: tuple, kwargs: dict) -> tuple[tuple, dict]:
        x = args[0] if args else kwargs.pop("hidden_states")
        bv, n, d = x.shape
        return (x.reshape(bv // views, views * n, d), *args[1:]), kwargs

    def after(module: nn.Module, args: tuple, kwargs: dict, out: torch.Tensor) -> torch.Tensor:
        b, vn, d = out.shape
        return out.reshape(b * views, vn // views, d)

    attn.register_forward_pre_hook(before, with_kwargs=True)
    attn.register_forward_hook(after, with_kwargs=True)


class SdTurboRefiner(nn.Module):
    """``forward(coarse, reference=None, normal=None)`` with [B, 3, H, W] in [0, 1] -> [B, V, 3, H, W] in [0, 1],
    the scratch :class:`~trioman.toolkit.refiner.model.Refiner`'s contract. H, W: multiples of ``total_downsample``
    (the VAE's times the U-Net's downsampling; 64 for SD-Turbo). ``exportable`` uses plain matmul/softmax attention."""

    def __init__(self, config: RefinerConfig, exportable: bool = False) -> None:
        super().__init__()
        from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
        from diffusers.models.attention_processor import AttnProcessor

        if config.pretrained_path is None:
            raise SdTurboFolderError("pretrained_path: the sd-turbo backbone needs a local SD-Turbo folder in diffusers layout")
        root = check_folder(config.pretrained_path)
        self.config = config
        self.views = config.views
        self.vae = AutoencoderKL.from_pretrained(str(root), subfolder="vae", local_files_only=True, low_cpu_mem_usage=False)
        self.unet = UNet2DConditionModel.from_pretrained(str(root), subfolder="unet", local_files_only=True, low_cpu_mem_usage=False)
        scheduler = DDPMScheduler.from_pretrained(str(root), subfolder="scheduler", local_files_only=True)
        if exportable:
            self.vae.set_attn_processor(AttnProcessor())
            self.unet.set_attn_processor(AttnProcessor())
        embeds = load_prompt_embedding(root)
        if embeds.shape[2] != self.unet.config.cross_attention_dim:
            raise SdTurboFolderError(f"{root / PROMPT_FILE}: prompt width {embeds.shape[2]} != unet cross_attention_dim {self.unet.config.cross_attention_dim}")
        self.register_buffer("prompt_embeds", embeds)
        a = float(scheduler.alphas_cumprod[TIMESTEP])
        self.sqrt_a, self.sqrt_1ma = a**0.5, (1.0 - a) ** 0.5
        self.prediction_type = scheduler.config.prediction_type
        if self.prediction_type not in ("epsilon", "v_prediction", "sample"):
            raise SdTurboFolderError(f"{root / 'scheduler' / 'scheduler_config.json'}: prediction_type {self.prediction_type!r} is not supported")
        enc_widths = list(self.vae.config.block_out_channels)
        dec_widths = enc_widths[::-1]
        # up block i's input meets down block (n-1-i)'s input: same resolution (pix2pix-turbo's skip_conv_1..n)
        n = len(enc_widths)
        self.skip_convs = nn.ModuleList(
            nn.Conv2d(enc_widths[max(n - 2 - i, 0)], dec_widths[max(i - 1, 0)], 1, bias=False) for i in range(n)
        )
        for conv in self.skip_convs:
            nn.init.constant_(conv.weight, SKIP_INIT)
        for module in (self.vae.encoder, self.vae.quant_conv):
            if module is not None:
                module.requires_grad_(False)
        for name, module in self.unet.named_modules():
            if name.endswith("attn1") and type(module).__name__ == "Attention":
                _span_views(module, self.views)
        self.vae_scale = 2 ** (len(enc_widths) - 1)
        self.total_downsample = self.vae_scale * 2 ** (len(self.unet.config.block_out_channels) - 1)

    @property
    def input_names(self) -> tuple[str, ...]:
        return INPUT_NAMES[: self.views]

    def enable_gradient_checkpointing(self) -> None:
        """Recompute the U-Net's and the VAE decoder's activations in the backward pass (diffusers' own)."""
        self.unet.enable_gradient_checkpointing()
        self.vae.enable_gradient_checkpointing()

    def check_inputs(self, coarse: torch.Tensor, reference: torch.Tensor | None, normal: torch.Tensor | None) -> None:
        """Raise ValueError/TypeError naming the argument for a missing or misshapen input."""
        check_refiner_inputs(self.input_names, self.config.conditions, self.total_downsample,
                             "sd-turbo's total downsampling", coarse, reference, normal)

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Images [N, 3, H, W] in [-1, 1] -> (scaled latent mean [N, c, h, w], the down blocks' inputs)."""
        enc = self.vae.encoder
        h = enc.conv_in(x)
        skips = []
        for block in enc.down_blocks:
            skips.append(h)
            h = block(h)
        h = enc.conv_out(enc.conv_act(enc.conv_norm_out(enc.mid_block(h))))
        if self.vae.quant_conv is not None:
            h = self.vae.quant_conv(h)
        mean = h[:, : self.vae.config.latent_channels]
        return (mean - (self.vae.config.shift_factor or 0.0)) * self.vae.config.scaling_factor, skips

    def decode(self, z: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        """Scaled latents [N, c, h, w] and the encoder's skips -> images [N, 3, H, W] in [-1, 1]."""
        dec = self.vae.decoder
        z = z / self.vae.config.scaling_factor + (self.vae.config.shift_factor or 0.0)
        if self.vae.post_quant_conv is not None:
            z = self.vae.post_quant_conv(z)
        h = dec.mid_block(dec.conv_in(z), None)
        checkpoint = torch.is_grad_enabled() and dec.gradient_checkpointing
        for block, conv, skip in zip(dec.up_blocks, self.skip_convs, reversed(skips)):
            h = h + conv(skip)
            h = dec._gradient_checkpointing_func(block, h, None) if checkpoint else block(h, None)
        return dec.conv_out(dec.conv_act(dec.conv_norm_out(h))).clamp(-1.0, 1.0)

    def forward(self, coarse: torch.Tensor, reference: torch.Tensor | None = None, normal: torch.Tensor | None = None) -> torch.Tensor:
        if not torch.jit.is_tracing():
            self.check_inputs(coarse, reference, normal)
        H, W = coarse.shape[2], coarse.shape[3]
        v = self.views
        x = torch.stack(view_images(self.config.conditions, coarse, reference, normal), dim=1).flatten(0, 1) * 2.0 - 1.0  # (B V)
        z, skips = self.encode(x)
        prompt = self.prompt_embeds.expand(z.shape[0], -1, -1).to(z.dtype)
        out = self.unet(z, TIMESTEP, encoder_hidden_states=prompt, return_dict=False)[0]
        if self.prediction_type == "epsilon":
            z0 = (z - self.sqrt_1ma * out) / self.sqrt_a
        elif self.prediction_type == "v_prediction":
            z0 = self.sqrt_a * z - self.sqrt_1ma * out
        else:
            z0 = out
        y = self.decode(z0, skips)
        return ((y + 1.0) * 0.5).reshape(-1, v, 3, H, W)


def write_tiny_folder(root: str | Path, seed: int = 0, cross_attention_dim: int = 16) -> Path:
    """A tiny random SD-Turbo-like folder in diffusers layout (tests, benchmarks): VAE widths (8, 16), U-Net
    widths (8, 16), a random prompt embedding [1, 8, cross_attention_dim]; total downsampling 4."""
    from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel

    root = Path(root)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        vae = AutoencoderKL(
            block_out_channels=(8, 16), down_block_types=("DownEncoderBlock2D",) * 2, up_block_types=("UpDecoderBlock2D",) * 2,
            latent_channels=4, layers_per_block=1, norm_num_groups=4, sample_size=32,
        )
        unet = UNet2DConditionModel(
            block_out_channels=(8, 16), layers_per_block=1, norm_num_groups=4, sample_size=16, in_channels=4, out_channels=4,
            down_block_types=("DownBlock2D", "CrossAttnDownBlock2D"), up_block_types=("CrossAttnUpBlock2D", "UpBlock2D"),
            cross_attention_dim=cross_attention_dim, attention_head_dim=4,
        )
        embeds = torch.randn(1, 8, cross_attention_dim)
    vae.save_pretrained(str(root / "vae"))
    unet.save_pretrained(str(root / "unet"))
    DDPMScheduler(beta_schedule="scaled_linear", beta_start=0.00085, beta_end=0.012, timestep_spacing="trailing").save_pretrained(
        str(root / "scheduler")
    )
    index = {"_class_name": "StableDiffusionPipeline", "vae": ["diffusers", "AutoencoderKL"],
             "unet": ["diffusers", "UNet2DConditionModel"], "scheduler": ["diffusers", "DDPMScheduler"]}
    (root / "model_index.json").write_text(json.dumps(index, indent=2))
    save_prompt_embedding(embeds, root)
    return root
