"""The sd-turbo backbone on a tiny random SD-Turbo-like folder that the tests build from configs and save in
diffusers layout (vae/, unet/, scheduler/, model_index.json, prompt_embeds.safetensors): shapes, views
attending to each other, a training step, save -> load, ONNX parity, augment with the exported model, and
a one-line error for each missing part of the folder."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("diffusers", reason="the sd-turbo backbone needs the diffusers package (pip install 'trioman[diffusion]')")
pytest.importorskip("onnx")  # the ONNX parity and export tests

from tests.toolkit.refiner.helpers import synthetic_batch  # noqa: E402
from trioman.toolkit.refiner import RefinerConfig, RefinerTrainConfig, create_refiner, load_refiner, refiner_loop  # noqa: E402
from trioman.toolkit.refiner.sd_turbo import PROMPT_FILE, SdTurboFolderError, SdTurboRefiner, write_tiny_folder  # noqa: E402
from trioman.toolkit.loops.checkpoint import model_checkpoint  # noqa: E402

S = 32  # image side; the tiny folder's total downsampling is 4


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    return write_tiny_folder(tmp_path_factory.mktemp("sd_turbo") / "tiny")


def config(folder: Path, **overrides) -> RefinerConfig:
    return RefinerConfig(**{"image_size": S, "backbone": "sd-turbo", "pretrained_path": str(folder), **overrides})


def onnx_error(model: torch.nn.Module, path: Path, size: int = S) -> float:
    """max |onnxruntime - torch| of the Refiner ONNX file ``path`` against ``model``, measured here on random frames."""
    from trioman.runtime.onnx_models import load_model

    names = ("coarse", "reference", "normal")
    x = {n: np.random.default_rng(i).random((2, 3, size, size), dtype=np.float32) for i, n in enumerate(names)}
    with torch.no_grad():
        want = model.eval()(*(torch.from_numpy(x[n]) for n in names)).numpy()
    return float(np.abs(load_model(path, "refiner").run(**x) - want).max())


@pytest.mark.parametrize("conditions", ["none", "tex", "tex+geo", "warp", "warp+geo"])
def test_forward_shapes_and_views_interact(folder, conditions):
    model = create_refiner(config(folder, conditions=conditions)).eval()
    assert isinstance(model, SdTurboRefiner) and model.total_downsample == 4
    g = torch.Generator().manual_seed(0)
    x = [torch.rand(2, 3, S, S, generator=g) for _ in range(3)]
    with torch.no_grad():
        y = model(*x)
        assert y.shape == (2, model.views, 3, S, S) and y.dtype == torch.float32
        assert 0.0 <= y.min() and y.max() <= 1.0
        # batch items stay independent
        assert torch.allclose(model(*(t[:1] for t in x)), y[:1], atol=1e-5)
        if model.views > 1:  # the coarse view's output depends on the reference: attention spans the views
            other = model(x[0], torch.rand(2, 3, S, S, generator=g), x[2])
            assert (other[:, 0] - y[:, 0]).abs().max() > 1e-4
    with pytest.raises(ValueError, match="multiples of 4"):
        model(*(t[..., :30] for t in x))


def test_encoder_frozen_and_skips_start_small(folder):
    model = create_refiner(config(folder))
    assert not any(p.requires_grad for p in model.vae.encoder.parameters())
    assert all(p.requires_grad for p in model.unet.parameters()) and all(p.requires_grad for p in model.vae.decoder.parameters())
    assert all(torch.all(c.weight == 1e-5) for c in model.skip_convs)
    assert "prompt_embeds" in model.state_dict()


def test_training_steps_lower_the_loss(folder):
    model = create_refiner(config(folder, conditions="tex"), seed=0)
    batch = synthetic_batch(0, batch=2, size=S)
    result = refiner_loop(model, lambda step: batch, RefinerTrainConfig(steps=4, lr=1e-3))
    assert result.skipped == 0 and result.losses[-1] < result.losses[0]


def test_gradient_checkpointing_and_bf16_run_on_cpu(folder):
    batch = synthetic_batch(0, batch=2, size=S)
    plain = refiner_loop(create_refiner(config(folder), seed=0), lambda s: batch, RefinerTrainConfig(steps=1))
    ckpt = refiner_loop(create_refiner(config(folder), seed=0), lambda s: batch,
                         RefinerTrainConfig(steps=1, gradient_checkpointing=True))
    assert ckpt.losses == pytest.approx(plain.losses, abs=1e-5)
    bf16 = refiner_loop(create_refiner(config(folder), seed=0), lambda s: batch, RefinerTrainConfig(steps=1, mixed_precision="bf16"))
    assert bf16.losses == pytest.approx(plain.losses, abs=0.05)


def test_save_then_load(folder, tmp_path):
    model = create_refiner(config(folder), seed=0)
    batch = synthetic_batch(0, batch=2, size=S)
    result = refiner_loop(model, lambda step: batch, RefinerTrainConfig(steps=2, lr=1e-3), run=tmp_path)
    loaded = load_refiner(result.checkpoint)
    with torch.no_grad():
        assert torch.equal(loaded(batch.coarse, batch.reference, batch.normal), model(batch.coarse, batch.reference, batch.normal))
    assert loaded.config == model.config


@pytest.fixture(scope="module")
def exported(folder, tmp_path_factory):
    from trioman.export.onnx_models import export_refiner_onnx

    model = create_refiner(config(folder), seed=0)
    with torch.no_grad():  # move the decoder off its random start so the views' outputs are not saturated
        for conv in model.skip_convs:
            conv.weight.normal_(0.0, 0.05)
    path = tmp_path_factory.mktemp("sd_turbo_onnx") / "refiner.onnx"
    entry = export_refiner_onnx(model, path, size=S, gate_frames=2)
    return path, entry, model


def test_onnx_parity_and_contract(exported):
    import onnx

    from trioman.runtime.onnx_models import load_model

    path, entry, model = exported
    assert entry["status"] == "written" and onnx_error(model, path) <= 1e-3
    proto = onnx.load(str(path))
    assert proto.opset_import[0].version == 17
    assert [d.dim_param for d in proto.graph.input[0].type.tensor_type.shape.dim][0] == "batch"
    meta = {p.key: p.value for p in proto.metadata_props}
    assert json.loads(meta["trioman.config"])["backbone"] == "sd-turbo" and meta["trioman.kind"] == "refiner"
    assert [i.name for i in proto.graph.input] == ["coarse", "reference", "normal"]  # no prompt or timestep input
    m = load_model(path, "refiner")
    out = m.run(**{n: np.random.default_rng(0).random((3, 3, S, S), dtype=np.float32) for n in ("coarse", "reference", "normal")})
    assert out.shape == (3, 3, 3, S, S)
    # any image size: H and W symbolic, padded to multiples of the model's total downsampling, parity at another size
    assert meta["trioman.size_multiple"] == str(model.total_downsample) == str(m.multiple)
    assert [d.dim_param for d in proto.graph.input[0].type.tensor_type.shape.dim][2:] == ["height", "width"]
    assert len(entry["parity"]["other_sizes"]) == 1 and max(entry["parity"]["other_sizes"].values()) <= 1e-3
    assert m.refine(*(np.random.default_rng(i).random((1, S + 1, S + 3, 3), dtype=np.float32) for i in range(3))).shape == \
        (1, S + 1, S + 3, 3)


def test_a_warp_refiner_exports_with_parity(folder, tmp_path):
    """warp+geo (the aligned reference as ``reference``, and the normal map): the same graph contract and parity."""
    from trioman.export.onnx_models import export_refiner_onnx
    from trioman.runtime.onnx_models import load_model

    model = create_refiner(config(folder, conditions="warp+geo"), seed=1)
    with torch.no_grad():
        for conv in model.skip_convs:
            conv.weight.normal_(0.0, 0.05)
    entry = export_refiner_onnx(model, tmp_path / "w.onnx", size=S, gate_frames=2)
    assert entry["status"] == "written" and onnx_error(model, tmp_path / "w.onnx") <= 1e-3
    m = load_model(tmp_path / "w.onnx", "refiner")
    assert m.conditions == "warp+geo" and m.input_names == ("coarse", "reference", "normal")


def test_augment_with_the_exported_model(exported, tiny_run, tmp_path):
    from trioman.cli import main
    from trioman.runtime.augment import augment
    from trioman.runtime.formats import load_avatar, load_subject

    avatar = tmp_path / "avatar"
    assert main(["export", "avatar", str(tiny_run), "--out", str(avatar)]) == 0
    subject = Path(load_avatar(avatar).meta["source"]["subject"])
    augment(subject, avatar, exported[0], tmp_path / "aug", None, frames="all", limit=2, seed=0, progress=False)
    assert load_subject(tmp_path / "aug").num_frames >= 2


PARTS = {  # what is removed -> what the message names
    "model_index.json": "model_index.json",
    "vae": "vae",
    "vae/config.json": "vae/config.json",
    "vae/diffusion_pytorch_model.safetensors": "vae/diffusion_pytorch_model.safetensors",
    "unet": "unet",
    "unet/diffusion_pytorch_model.safetensors": "unet/diffusion_pytorch_model.safetensors",
    "scheduler": "scheduler/scheduler_config.json",
    PROMPT_FILE: "tokenizer",
}


@pytest.mark.parametrize("part", sorted(PARTS))
def test_missing_part_is_one_line_naming_it(folder, tmp_path, part):
    root = tmp_path / "copy"
    shutil.copytree(folder, root)
    target = root / part
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    with pytest.raises(SdTurboFolderError) as err:
        create_refiner(config(root))
    message = str(err.value)
    assert "\n" not in message and str(root / PARTS[part]) in message


def test_no_folder_says_so(tmp_path):
    with pytest.raises(SdTurboFolderError, match="pretrained_path"):
        create_refiner(RefinerConfig(image_size=S, backbone="sd-turbo"))
    with pytest.raises(SdTurboFolderError, match="not a folder"):
        create_refiner(RefinerConfig(image_size=S, backbone="sd-turbo", pretrained_path=str(tmp_path / "nope")))


def test_train_refiner_and_export_commands(folder, corpus, tmp_path):
    from trioman.cli import main

    run = tmp_path / "run"
    assert main(["train-refiner", "--corpus", str(corpus), "--out", str(run), "--steps", "2", "--batch", "2", "--crop", "32",
                 "--backbone", "sd-turbo", "--pretrained", str(folder), "--gradient-checkpointing"]) == 0
    info = json.loads((run / "fit.json").read_text())
    assert info["config"]["backbone"] == "sd-turbo" and info["config"]["pretrained_path"] == str(folder)
    assert main(["export", "onnx", "--refiner", str(run), "--out", str(tmp_path / "onnx"), "--variants", "fp32"]) == 0
    assert onnx_error(load_refiner(model_checkpoint(run)), tmp_path / "onnx" / "refiner.onnx") <= 1e-3


def test_export_over_the_protobuf_limit_writes_external_data(folder, tmp_path, monkeypatch):
    from trioman.export import onnx_models
    from trioman.export.onnx_models import jobs

    monkeypatch.setattr(jobs, "MAX_PROTO_BYTES", 1000)  # stands in for SD-Turbo's 3.8 GB of fp32 weights
    model = create_refiner(config(folder), seed=0)
    report = onnx_models.export_onnx(refiner=model, out=tmp_path / "onnx", size=S, variants="fp32,fp16", gate_frames=2)
    entry = report["files"]["refiner.onnx"]
    assert entry["external_data"]["file"] == "refiner.onnx.data" and entry["external_data"]["bytes"] > 100_000
    assert entry["parity_max_abs"] <= 1e-3 and report["files"]["refiner.fp16.onnx"]["status"] == "written"
    one = tmp_path / "one.onnx"  # a single file moves with its weights
    onnx_models.export_refiner_onnx(model, one, size=S, gate_frames=2)
    assert (tmp_path / "refiner.onnx.data").is_file()
    assert onnx_error(model, one) <= 1e-3


def test_bench_models_with_the_sd_turbo_backbone(folder, corpus, tmp_path):
    from trioman.bench.models import ModelsBenchConfig, bench_models

    r = bench_models(ModelsBenchConfig(corpus=str(corpus), subjects=2, heldout=1, size=S, out=str(tmp_path / "bench"),
                                       refiner_steps=1, examiner_steps=1, batch=2, examiner="examiner_nano", crop=32,
                                       refiner_size="compact", baseline_frames=("all",), backbone="sd-turbo",
                                       pretrained=str(folder)))
    assert r["refiner_backbone"] == "sd-turbo" and (tmp_path / "bench" / "runs" / "refiner_tex_geo_sd_turbo").is_dir()
    assert all(np.isfinite(v) for m in r["metrics"].values() for v in m.values()) and r["inference"]["refiner_tex+geo_ms"] > 0


def test_sizes_follow_the_model_not_the_scratch_config(folder, tmp_path):
    from trioman.export.onnx_models import export_refiner_onnx
    from trioman.toolkit.train.augment_models import TorchRefiner

    model = create_refiner(config(folder))  # RefinerConfig's scratch widths would ask for multiples of 16
    assert model.config.total_downsample == 16 and TorchRefiner(model, tmp_path).multiple == 4
    entry = export_refiner_onnx(model, tmp_path / "r36.onnx", size=36, gate_frames=2)
    assert entry["input_size"] == [36, 36] and onnx_error(model, tmp_path / "r36.onnx", 36) <= 1e-3
