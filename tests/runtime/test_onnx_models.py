"""trioman.runtime.onnx_models: the onnxruntime wrappers of the exported Refiner and Examiner, and the clear
errors of their loaders. The models are exported once (tiny, fp32) with trioman.export.onnx_models; the tests of a
Refiner's image size (padding, older fixed-size files) also run on a stand-in graph built without torch."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import run_python
from tests.runtime.factories import block_means, block_refiner, fixed_size_copy
from trioman.runtime.formats import FormatError
from trioman.runtime.onnx_models import (
    Choice,
    ExaminerModel,
    RefinerModel,
    crop_to,
    load_model,
    pad_to_multiple,
    padded_size,
    read_metadata,
)

S = 32


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """refiner.onnx (tex+geo), refiner_none.onnx (conditions "none") and examiner.onnx, all exported at 32x32;
    refiner_fixed.onnx: refiner.onnx as an older export has it (32x32 only)."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("onnx")
    from trioman.export.onnx_models import export_examiner_onnx, export_refiner_onnx
    from trioman.toolkit.examiner import ExaminerConfig, create_examiner
    from trioman.toolkit.refiner import RefinerConfig, create_refiner

    root = tmp_path_factory.mktemp("runtime_models")
    base = dict(image_size=S, latent_channels=4, latent_downsample=4, vae_widths=(8, 16, 16), unet_widths=(16, 16),
                norm_groups=4, attention_heads=2)
    for name, conditions in (("refiner.onnx", "tex+geo"), ("refiner_none.onnx", "none")):
        model = create_refiner(RefinerConfig(**base, conditions=conditions), seed=0)
        g = torch.Generator().manual_seed(0)
        with torch.no_grad():  # open the zero-initialised output convs: not the identity
            for p in model.parameters():
                if not p.any():
                    p.copy_(0.05 * torch.randn(p.shape, generator=g))
        export_refiner_onnx(model, root / name, gate_frames=4, calibration_frames=4)
    fixed_size_copy(root / "refiner.onnx", root / "refiner_fixed.onnx")
    torch.manual_seed(0)
    examiner = create_examiner(ExaminerConfig(img_size=S, patch_size=8, embed_dim=32, depth=1, num_heads=2, dual_dims=(16, 8),
                                              dual_heads=2, head_hidden=16))
    with torch.no_grad():  # move the heads off their init so scores differ between pairs
        for p in examiner.parameters():
            p.add_(0.05 * torch.randn_like(p))
    export_examiner_onnx(examiner, root / "examiner.onnx", gate_frames=4, calibration_frames=4)
    return root


def images(n: int, size: int = S, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).random((n, size, size, 3), dtype=np.float32)


def edited(src: Path, dst: Path, **changes: str | None) -> Path:
    """A copy of ``src`` with metadata keys (``trioman_kind`` -> 'trioman.kind') changed, or removed when None."""
    import onnx

    proto = onnx.load(str(src))
    meta = {p.key: p.value for p in proto.metadata_props}
    for key, value in changes.items():
        key = key.replace("_", ".", 1)
        if value is None:
            meta.pop(key)
        else:
            meta[key] = value
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    onnx.save(proto, str(dst))
    return dst


# --------------------------------------------------------------------------------------------------
# the Refiner


def test_refiner_refine_shapes_and_single_vs_batch(models):
    m = RefinerModel(models / "refiner.onnx")
    assert m.size == (S, S) and m.conditions == "tex+geo" and m.input_names == ("coarse", "reference", "normal")
    assert m.multiple == 8 and m.meta["trioman.size_multiple"] == "8"  # the tiny model's total downsampling
    assert m.precision == "fp32" and m.meta["trioman.kind"] == "refiner"
    c, r, n = images(3, seed=1), images(3, seed=2), images(3, seed=3)
    batch = m.refine(c, r, n)
    assert batch.shape == (3, S, S, 3) and batch.dtype == np.float32
    assert batch.min() >= 0 and batch.max() <= 1 and np.abs(batch - c).max() > 1e-3  # not the identity
    single = m.refine(c[1], r[1], n[1])
    assert single.shape == (S, S, 3)
    np.testing.assert_allclose(single, batch[1], atol=1e-5)
    raw = m.run(c.transpose(0, 3, 1, 2), r.transpose(0, 3, 1, 2), n.transpose(0, 3, 1, 2))
    assert raw.shape == (3, 3, 3, S, S)
    np.testing.assert_allclose(np.clip(raw[:, 0].transpose(0, 2, 3, 1), 0, 1), batch, atol=1e-6)


def test_a_refiner_that_outputs_nan_is_named_as_the_fault(models):
    # issue 41, U4: a NaN output was reported as the output image's fault
    m = RefinerModel(models / "refiner.onnx")
    real = m.session

    class NaNSession:  # what a model exported from a diverged checkpoint returns
        def run(self, names, feed):
            out = real.run(names, feed)
            out[0][0, 0, 1, 2, 3] = np.nan
            return out

    m.session = NaNSession()
    with pytest.raises(ValueError, match=rf"^refiner: {models / 'refiner.onnx'}: its output holds 1 NaN or Inf value\(s\) on finite inputs"):
        m.refine(images(1, seed=1)[0], images(1, seed=2)[0], images(1, seed=3)[0])


def test_sessions_plan_no_memory_pattern(models):
    """A memory pattern would allocate a second set of activations on top of the arena's (see _session)."""
    for path, kind in ((models / "refiner.onnx", "refiner"), (models / "examiner.onnx", "examiner")):
        assert load_model(path, kind).session.get_session_options().enable_mem_pattern is False


def test_refiner_inputs_errors(models):
    m = RefinerModel(models / "refiner.onnx", optimization="basic", threads=1)
    c = images(1)[0]
    with pytest.raises(ValueError, match=r"^normal: required by this Refiner \(conditions='tex\+geo'\)"):
        m.refine(c, c, None)
    with pytest.raises(ValueError, match=r"^reference: image size \(H, W\) = \(16, 16\) differs from coarse's \(32, 32\)"):
        m.refine(c, images(1, 16)[0], c)
    with pytest.raises(ValueError, match=r"^normal: image size \(H, W\) = \(16, 16\) differs from coarse's \(32, 32\)"):
        m.run(*(images(1).transpose(0, 3, 1, 2) for _ in range(2)), images(1, 16).transpose(0, 3, 1, 2))
    with pytest.raises(ValueError, match="coarse: expected float images in \\[0, 1\\], got dtype uint8"):
        m.refine((c * 255).astype(np.uint8), c, c)
    with pytest.raises(ValueError, match=r"coarse: expected an image \[H, W, 3\]"):
        m.refine(c[..., :2], c, c)
    with pytest.raises(ValueError, match="batch sizes differ"):
        m.refine(images(2), images(3), images(2))
    with pytest.raises(ValueError, match=r"^reference: required by this Refiner"):
        m.run(images(1, 16).transpose(0, 3, 1, 2), None, None)


def test_an_older_fixed_size_export_loads_and_refuses_other_sizes(models):
    """A file without trioman.size_multiple (exported before it) keeps its one size, with the errors it always had."""
    m = RefinerModel(models / "refiner_fixed.onnx")
    assert m.size == (S, S) and m.multiple is None and "multiple" not in repr(m)
    assert m.takes(S, S) and not m.takes(S, 2 * S) and not m.takes(24, 40)
    c, r, n = images(2, seed=1), images(2, seed=2), images(2, seed=3)
    np.testing.assert_allclose(m.refine(c, r, n), RefinerModel(models / "refiner.onnx").refine(c, r, n), atol=1e-6)
    with pytest.raises(ValueError, match=r"^reference: image size \(H, W\) = \(16, 16\) differs from the model's \(32, 32\) "
                                         r"\(this Refiner was exported for 32x32 images\)"):
        m.refine(c[0], images(1, 16)[0], c[0])
    with pytest.raises(ValueError, match=r"^coarse: image size \(H, W\) = \(24, 24\) differs from the model's \(32, 32\)"):
        m.refine(images(1, 24), images(1, 24), images(1, 24))
    with pytest.raises(ValueError, match=r"^coarse: image size \(H, W\) = \(16, 16\) differs from the model's \(32, 32\)"):
        m.run(*(images(1, 16).transpose(0, 3, 1, 2) for _ in range(3)))


def test_an_exported_refiner_takes_other_sizes_padded_to_its_multiple(models):
    """The exported graph at other sizes: a multiple of 8 as it is, a size that is not padded (edge) and cropped."""
    m = RefinerModel(models / "refiner.onnx")
    for H, W in ((24, 48), (30, 45)):
        c, r, n = (np.random.default_rng(i).random((2, H, W, 3), dtype=np.float32) for i in range(3))
        assert m.takes(H, W)
        out = m.refine(c, r, n)
        assert out.shape == (2, H, W, 3) and np.abs(out - c).max() > 1e-3
        raw = m.run(*(x.transpose(0, 3, 1, 2) for x in (c, r, n)))
        assert raw.shape == (2, 3, 3, H, W) and raw.flags.c_contiguous
        padded = m.run(*(pad_to_multiple(x, 8).transpose(0, 3, 1, 2) for x in (c, r, n)))  # the graph on the padded images
        np.testing.assert_allclose(raw, crop_to(padded, (H, W), (-2, -1)), atol=1e-6)


def test_refiner_ignores_inputs_its_conditions_do_not_use(models):
    m = load_model(models / "refiner_none.onnx")
    assert isinstance(m, RefinerModel) and m.conditions == "none" and m.input_names == ("coarse",)
    c = images(2)
    out = m.refine(c)
    np.testing.assert_array_equal(m.refine(c, reference=images(1, 16), normal="ignored"), out)
    assert m.run(c.transpose(0, 3, 1, 2)).shape == (2, 1, 3, S, S)


# --------------------------------------------------------------------------------------------------
# any image size, without torch: the padding helpers and a stand-in Refiner graph


def test_pad_to_multiple_replicates_the_bottom_row_and_right_column_and_crop_to_undoes_it():
    x = np.arange(2 * 5 * 7 * 3, dtype=np.float32).reshape(2, 5, 7, 3)  # HWC batch
    p = pad_to_multiple(x, 4)
    assert p.shape == (2, 8, 8, 3) and padded_size(5, 7, 4) == (8, 8) and padded_size(540, 304, 16) == (544, 304)
    np.testing.assert_array_equal(p[:, :5, :7], x)
    np.testing.assert_array_equal(p[:, 5:, :7], np.repeat(x[:, 4:5], 3, axis=1))  # the last row, repeated
    np.testing.assert_array_equal(p[:, :, 7], p[:, :, 6])  # the last column
    np.testing.assert_array_equal(crop_to(p, (5, 7)), x)
    assert pad_to_multiple(x, 1) is x and crop_to(x, (5, 7)) is x  # nothing to do: the array itself
    nchw = np.ascontiguousarray(x.transpose(0, 3, 1, 2))
    np.testing.assert_array_equal(pad_to_multiple(nchw, 4, (-2, -1)), p.transpose(0, 3, 1, 2))
    np.testing.assert_array_equal(pad_to_multiple(x[0], 4), p[0])  # one image [H, W, 3]
    with pytest.raises(ValueError, match="^multiple: expected a positive integer, got 0"):
        pad_to_multiple(x, 0)
    with pytest.raises(ValueError, match=r"^size: \(9, 7\) exceeds the images' \(5, 7\)"):
        crop_to(x, (9, 7))


@pytest.mark.parametrize("size", [(32, 32), (24, 40), (30, 45), (17, 9)])
def test_a_refiner_of_any_size_pads_its_input_and_crops_its_output(tmp_path, size):
    """sides that are not multiples of trioman.size_multiple go through the graph padded (edge) to the next multiple,
    and the output is cropped back: exactly the graph's output on the padded images."""
    pytest.importorskip("onnx")
    m = load_model(block_refiner(tmp_path / "r.onnx", multiple=8))
    assert m.size == (32, 32) and m.multiple == 8 and m.takes(*size) and "multiple=8" in repr(m)
    H, W = size
    x = np.random.default_rng(0).random((2, H, W, 3), dtype=np.float32)
    want = crop_to(block_means(pad_to_multiple(x, 8), 8), size, (-2, -1))
    np.testing.assert_allclose(m.run(np.ascontiguousarray(x.transpose(0, 3, 1, 2))), want, atol=1e-6)
    got = m.refine(x)
    assert got.shape == x.shape
    np.testing.assert_allclose(got, want[:, 0].transpose(0, 2, 3, 1), atol=1e-6)
    np.testing.assert_allclose(m.refine(x[1]), got[1], atol=1e-6)


def test_a_fixed_size_refiner_without_the_key_refuses_other_sizes(tmp_path):
    pytest.importorskip("onnx")
    m = RefinerModel(block_refiner(tmp_path / "r.onnx", multiple=8, dims=(32, 32)))
    assert m.multiple is None and m.takes(32, 32) and not m.takes(30, 45)
    x = np.random.default_rng(0).random((1, 32, 32, 3), dtype=np.float32)
    np.testing.assert_allclose(m.refine(x), block_means(x, 8)[:, 0].transpose(0, 2, 3, 1), atol=1e-6)
    with pytest.raises(ValueError, match=r"^coarse: image size \(H, W\) = \(30, 45\) differs from the model's \(32, 32\) "
                                         r"\(this Refiner was exported for 32x32 images\)"):
        m.refine(np.zeros((30, 45, 3), np.float32))


def test_size_multiple_metadata_problems(tmp_path):
    pytest.importorskip("onnx")
    src = block_refiner(tmp_path / "r.onnx", multiple=8)
    for value in ("0", "eight", "-8", ""):
        with pytest.raises(FormatError, match=rf"metadata 'trioman\.size_multiple': expected a positive integer, got '{value}'"):
            load_model(edited(src, tmp_path / "a.onnx", trioman_size_multiple=value))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.input_size' 30,32 is not a multiple of 'trioman\.size_multiple' 8"):
        load_model(edited(src, tmp_path / "b.onnx", trioman_input_size="30,32"))
    fixed = block_refiner(tmp_path / "f.onnx", multiple=8, dims=(32, 32))
    with pytest.raises(FormatError, match=r"graph input 'coarse': shape \['batch', 3, 32, 32\] disagrees with metadata "
                                          r"'trioman\.size_multiple' \(expected \[batch, 3, height, width\]"):
        load_model(edited(fixed, tmp_path / "c.onnx", trioman_size_multiple="8"))


# --------------------------------------------------------------------------------------------------
# the Examiner


def test_examiner_score_shapes_single_vs_batch_and_resize(models):
    import cv2

    m = ExaminerModel(models / "examiner.onnx")
    assert m.size == (S, S) and m.precision == "fp32"
    c, r = images(4, seed=1), images(4, seed=2)
    batch = m.score(c, r)
    assert batch.shape == (4,) and batch.dtype == np.float32 and batch.std() > 1e-4
    single = m.score(c[2], r[2])
    assert single.shape == (1,)
    np.testing.assert_allclose(single[0], batch[2], atol=1e-6)
    np.testing.assert_allclose(m.score(c, r[0]), m.score(c, np.stack([r[0]] * 4)), atol=1e-6)  # one reference for all
    np.testing.assert_allclose(m.run(c.transpose(0, 3, 1, 2), r.transpose(0, 3, 1, 2)), batch, atol=1e-6)
    # Another size: resized with cv2.INTER_AREA to the model's size.
    big_c, big_r = images(2, 64, seed=5), images(2, 48, seed=6)
    want = m.score(np.stack([cv2.resize(x, (S, S), interpolation=cv2.INTER_AREA) for x in big_c]),
                   np.stack([cv2.resize(x, (S, S), interpolation=cv2.INTER_AREA) for x in big_r]))
    np.testing.assert_allclose(m.score(big_c, big_r), want, atol=1e-6)
    with pytest.raises(ValueError, match="reference: batch 3 differs from candidate batch 2"):
        m.score(images(2), images(3))
    with pytest.raises(ValueError, match=r"candidate: image size \(H, W\) = \(16, 16\)"):
        m.run(images(1, 16).transpose(0, 3, 1, 2), images(1).transpose(0, 3, 1, 2))


def test_examiner_choose_ties_threshold_and_inputs(models):
    m = ExaminerModel(models / "examiner.onnx")
    real, a, b = images(3, seed=7)
    scores = m.score(np.stack([a, b]), real)
    best, worst = (a, b) if scores[0] > scores[1] else (b, a)
    choice = m.choose([worst, best, best], real)
    assert isinstance(choice, Choice) and choice.index == 1 and choice.keep is True  # tie between 1 and 2 -> 1
    assert choice.scores.shape == (3,) and choice.score == pytest.approx(float(choice.scores.max()))
    assert m.choose(np.stack([best, best]), real).index == 0
    same = m.choose(np.stack([worst, best, best]), real)
    assert same.index == choice.index and np.array_equal(same.scores, choice.scores)
    assert m.choose([best], real, threshold=choice.score).keep is True  # keep = score >= threshold
    assert m.choose([best], real, threshold=min(1.0, choice.score + 1e-3)).keep is False
    assert m.choose([worst, best], real, threshold=0.0).keep is True
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="threshold: must lie in \\[0, 1\\]"):
            m.choose([best], real, threshold=bad)
    with pytest.raises(ValueError, match="candidates: expected at least one"):
        m.choose([], real)
    with pytest.raises(ValueError, match="real: expected one image"):
        m.choose([best], np.stack([real, real]))


# --------------------------------------------------------------------------------------------------
# loading errors


def test_load_model_dispatches_on_kind_and_checks_it(models):
    assert isinstance(load_model(models / "examiner.onnx"), ExaminerModel)
    assert isinstance(load_model(models / "refiner.onnx", "refiner", threads=1), RefinerModel)
    with pytest.raises(FormatError, match=r"examiner\.onnx: metadata 'trioman\.kind': expected 'refiner', got 'examiner'"):
        RefinerModel(models / "examiner.onnx")
    with pytest.raises(FormatError, match=r"refiner\.onnx: metadata 'trioman\.kind': expected 'examiner', got 'refiner'"):
        ExaminerModel(models / "refiner.onnx")
    with pytest.raises(FormatError, match="expected 'refiner', got 'examiner'"):
        load_model(models / "examiner.onnx", kind="refiner")
    with pytest.raises(ValueError, match="optimization"):
        load_model(models / "examiner.onnx", optimization="max")
    with pytest.raises(ValueError, match="threads"):
        ExaminerModel(models / "examiner.onnx", threads=0)


def test_missing_and_garbage_files(models, tmp_path):
    with pytest.raises(FormatError, match=r"nope\.onnx: missing file"):
        load_model(tmp_path / "nope.onnx")
    (tmp_path / "garbage.onnx").write_bytes(b"this is not a protobuf" * 10)
    with pytest.raises(FormatError, match=r"garbage\.onnx: not a loadable ONNX model"):
        RefinerModel(tmp_path / "garbage.onnx")
    with pytest.raises(FormatError, match="missing file"):
        read_metadata(tmp_path / "nope.onnx")


def test_metadata_problems(models, tmp_path):
    pytest.importorskip("onnx")
    src = models / "refiner.onnx"
    with pytest.raises(FormatError, match=r"metadata 'trioman\.kind' missing: not a model written by `trioman export onnx`"):
        load_model(edited(src, tmp_path / "a.onnx", trioman_kind=None))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.conditions' missing"):
        RefinerModel(edited(src, tmp_path / "b.onnx", trioman_conditions=None))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.format_version': unknown version '2'"):
        load_model(edited(src, tmp_path / "c.onnx", trioman_format_version="2"))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.format': expected 'trioman-onnx'"):
        load_model(edited(src, tmp_path / "d.onnx", trioman_format="other"))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.input_size': expected 'H,W'"):
        load_model(edited(src, tmp_path / "e.onnx", trioman_input_size="32"))
    with pytest.raises(FormatError, match=r"metadata 'trioman\.inputs': expected \['coarse', 'reference', 'normal'\]"):
        load_model(edited(src, tmp_path / "f.onnx", trioman_inputs=json.dumps(["coarse", "normal", "reference"])))
    assert read_metadata(edited(src, tmp_path / "g.onnx", trioman_kind=None)).get("trioman.kind") is None


def test_a_stale_model_whose_graph_disagrees_with_its_metadata(models, tmp_path):
    pytest.importorskip("onnx")
    stale = edited(models / "examiner.onnx", tmp_path / "stale.onnx", trioman_input_size="64,64")
    with pytest.raises(FormatError, match=r"stale\.onnx: graph input 'candidate': shape \['batch', 3, 32, 32\] disagrees "
                                          r"with metadata 'trioman\.input_size' 64,64"):
        ExaminerModel(stale)
    with pytest.raises(FormatError, match=r"metadata 'trioman\.size_multiple': the Examiner takes one size"):
        ExaminerModel(edited(models / "examiner.onnx", tmp_path / "sized.onnx", trioman_size_multiple="8"))
    renamed = edited(models / "refiner_none.onnx", tmp_path / "renamed.onnx", trioman_conditions="tex",
                     trioman_inputs=json.dumps(["coarse", "reference"]))
    with pytest.raises(FormatError, match=r"graph inputs \['coarse'\] disagree with metadata 'trioman\.inputs'"):
        RefinerModel(renamed)


# --------------------------------------------------------------------------------------------------
# without torch


def test_runtime_models_work_where_torch_cannot_be_imported(models):
    proc = run_python(f"""
        import sys
        import numpy as np
        from trioman.runtime.onnx_models import ExaminerModel, RefinerModel, load_model
        r = load_model({str(models / 'refiner.onnx')!r})
        x = np.random.default_rng(0).random((2, {S}, {S}, 3), dtype=np.float32)
        assert r.refine(x, x, x).shape == x.shape
        y = np.random.default_rng(1).random((1, 30, 45, 3), dtype=np.float32)  # not a multiple of its 8: padded
        assert r.refine(y, y, y).shape == y.shape
        e = ExaminerModel({str(models / 'examiner.onnx')!r})
        c = e.choose(x, x[0], threshold=0.5)
        assert c.scores.shape == (2,) and e.score(x[0], x[1]).shape == (1,)
        assert "torch" not in sys.modules or sys.modules["torch"] is None
        assert "onnx" not in sys.modules, "the runtime must not import onnx"
        print("ok", c.index)
    """, block_torch=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("ok")
