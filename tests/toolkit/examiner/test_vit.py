"""The timm-style ViT backbone: timm parameter names, strict loading of a local state dict."""

from __future__ import annotations

import pytest
import torch

from tests.toolkit.examiner.helpers import TINY
from trioman.toolkit.examiner import create_examiner, export_inputs
from trioman.toolkit.examiner.vit import VisionTransformer, load_timm_weights, resample_pos_embed

# timm's VisionTransformer(depth=1, num_classes=0, global_pool='token') state-dict keys
TIMM_KEYS = {
    "cls_token", "pos_embed", "patch_embed.proj.weight", "patch_embed.proj.bias",
    "blocks.0.norm1.weight", "blocks.0.norm1.bias", "blocks.0.attn.qkv.weight", "blocks.0.attn.qkv.bias",
    "blocks.0.attn.proj.weight", "blocks.0.attn.proj.bias", "blocks.0.norm2.weight", "blocks.0.norm2.bias",
    "blocks.0.mlp.fc1.weight", "blocks.0.mlp.fc1.bias", "blocks.0.mlp.fc2.weight", "blocks.0.mlp.fc2.bias",
    "norm.weight", "norm.bias",
}  # fmt: skip


def test_parameter_names_follow_timm():
    vit = VisionTransformer(img_size=32, patch_size=8, embed_dim=32, depth=1, num_heads=2)
    assert set(vit.state_dict()) == TIMM_KEYS
    assert vit.pos_embed.shape == (1, 1 + 16, 32) and vit.cls_token.shape == (1, 1, 32)


def test_state_dict_round_trip_through_a_local_file(tmp_path):
    source = create_examiner(TINY)
    path = tmp_path / "vit.pth"
    torch.save({"model": {**source.backbone.state_dict(), "head.weight": torch.zeros(10, 32), "head.bias": torch.zeros(10)}}, path)
    loaded = create_examiner(TINY, pretrained_path=str(path))
    for key, value in source.backbone.state_dict().items():
        torch.testing.assert_close(loaded.backbone.state_dict()[key], value, rtol=0, atol=0)
    c, r = export_inputs(TINY, batch=2)
    torch.testing.assert_close(loaded.features(c), source.features(c))


def test_safetensors_file_loads(tmp_path):
    safetensors = pytest.importorskip("safetensors.torch")
    source = create_examiner(TINY)
    path = tmp_path / "model.safetensors"
    safetensors.save_file({k: v.contiguous() for k, v in source.backbone.state_dict().items()}, str(path))
    loaded = create_examiner(TINY, pretrained_path=str(path))
    torch.testing.assert_close(loaded.backbone.pos_embed, source.backbone.pos_embed, rtol=0, atol=0)


def test_missing_and_unexpected_keys_are_listed():
    vit = VisionTransformer(img_size=32, patch_size=8, embed_dim=32, depth=1, num_heads=2)
    state = dict(vit.state_dict())
    del state["blocks.0.attn.qkv.bias"]
    state["blocks.1.norm1.weight"] = torch.ones(32)
    with pytest.raises(ValueError, match=r"missing \['blocks.0.attn.qkv.bias'\]; unexpected \['blocks.1.norm1.weight'\]"):
        load_timm_weights(vit, state)


def test_shape_mismatch_is_listed_and_missing_file_named(tmp_path):
    vit = VisionTransformer(img_size=32, patch_size=8, embed_dim=32, depth=1, num_heads=2)
    wider = VisionTransformer(img_size=32, patch_size=8, embed_dim=64, depth=1, num_heads=2)
    with pytest.raises(ValueError, match=r"tensor shapes do not match .*norm.weight: \(64,\) vs \(32,\)"):
        load_timm_weights(vit, wider.state_dict())
    with pytest.raises(FileNotFoundError, match="pretrained_path: .*nope.pth: no such file"):
        create_examiner(TINY, pretrained_path=str(tmp_path / "nope.pth"))


def test_pos_embed_of_another_image_size_is_resampled():
    big = VisionTransformer(img_size=64, patch_size=8, embed_dim=32, depth=1, num_heads=2)  # 8x8 grid
    small = VisionTransformer(img_size=32, patch_size=8, embed_dim=32, depth=1, num_heads=2)  # 4x4 grid
    load_timm_weights(small, big.state_dict())
    torch.testing.assert_close(small.pos_embed[:, :1], big.pos_embed[:, :1])
    torch.testing.assert_close(small.pos_embed, resample_pos_embed(big.pos_embed.detach(), 4))
    # a constant position field stays constant
    flat = torch.ones(1, 1 + 64, 3)
    torch.testing.assert_close(resample_pos_embed(flat, 4), torch.ones(1, 17, 3))
