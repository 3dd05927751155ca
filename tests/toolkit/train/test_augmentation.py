"""Online augmentation in the avatar's training: every mode trains, resume is exact, bad models give one line."""

import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("anny")

from tests.toolkit.train.conftest import SIZE  # noqa: E402
from tests.toolkit.train.factories import TINY_AVATAR, losses  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.toolkit.train.augmentation import AugmentConfig  # noqa: E402
from trioman.toolkit.loops.checkpoint import list_checkpoints, load_checkpoint  # noqa: E402
from trioman.toolkit.train.config import TrainConfig  # noqa: E402
from trioman.toolkit.train.loop import AUGMENT_JSON, train  # noqa: E402
from trioman.toolkit.train.augment_models import load_pseudo_examiner, load_pseudo_refiner  # noqa: E402


def augment_cfg(mode: str, models, **kw) -> AugmentConfig:
    paths = {"coarse": {}, "aligned": {}, "truth": {}, "refined": {"refiner": str(models["refiner"])},
             "examined": {"refiner": str(models["refiner"]), "examiner": str(models["examiner"])}}[mode]
    return AugmentConfig(mode=mode, start=0.25, refresh=10, pool=2, **paths, **kw)


@pytest.mark.parametrize("mode", ["coarse", "aligned", "truth", "refined", "examined"])
def test_each_mode_trains_on_pseudo_frames_and_lowers_the_loss(subject, models, tmp_path, mode):
    cfg = TrainConfig(iterations=40, lr=1e-2, random_background=False, checkpoint_every=40, avatar=TINY_AVATAR,
                      augment=augment_cfg(mode, models))
    run = train(subject, tmp_path / mode, cfg, progress=False)
    loss = losses(run)
    assert len(loss) == 40 and np.all(np.isfinite(loss))
    assert loss[-10:].mean() < 0.8 * loss[:10].mean(), (loss[:10].mean(), loss[-10:].mean())
    summary = json.loads((run / AUGMENT_JSON).read_text())
    assert summary["mode"] == mode and summary["start_step"] == 10 and summary["rebuilds"] == 3
    # Entries are made when first drawn: at most the 6 drawn at the rebuilds, at least one per pseudo step's entry.
    assert summary["entries"] == 6 and 1 <= summary["kept"] <= min(6, summary["pseudo_steps"]) < 30
    assert summary["candidates"] == summary["kept"] * (2 if mode == "examined" else 1) and summary["dropped"] == 0
    # What a mode does not need is never run.
    used = {k for k, v in summary["seconds"].items() if v > 0}
    assert used == {"coarse": {"generate", "render", "align"}, "aligned": {"generate", "render", "align"},
                    "truth": {"generate", "render"}, "refined": {"generate", "render", "align", "normal", "refine"},
                    "examined": {"generate", "render", "align", "normal", "refine", "examine"}}[mode]
    if mode == "truth":  # the subject's own renderer brings its mask: nothing is aligned
        assert summary["mean_body_coverage"] is None
    else:
        assert 0.3 < summary["mean_body_coverage"] <= 1.0  # the carried mask aligns every draw
    saved = json.loads((run / "config.json").read_text())
    # the record holds the config as trained: the subject-dependent defaults resolved (a synthetic subject: no pose
    # corrections)
    assert TrainConfig.from_dict(saved["train"]) == dataclasses.replace(cfg, refine_poses=False)


def test_resume_of_an_augmented_run_matches_an_uninterrupted_run_and_differs_from_the_plain_one(subject, models, tmp_path,
                                                                                                two_threads):
    cfg = TrainConfig(iterations=12, checkpoint_every=4, avatar=TINY_AVATAR,
                      augment=AugmentConfig(mode="examined", refiner=str(models["refiner"]), examiner=str(models["examiner"]),
                                            start=0.25, refresh=5, pool=2, share=0.6))
    straight = train(subject, tmp_path / "a", cfg, progress=False)
    broken = train(subject, tmp_path / "b", cfg, progress=False, stop_after=6)  # killed between refreshes
    train(subject, broken, cfg, resume=True, progress=False)
    a, b = load_checkpoint(list_checkpoints(straight)[-1]), load_checkpoint(list_checkpoints(broken)[-1])
    for key in a["model"]:
        torch.testing.assert_close(a["model"][key], b["model"][key], rtol=0, atol=0)
    np.testing.assert_array_equal(losses(straight), losses(broken))
    sa, sb = (json.loads((r / AUGMENT_JSON).read_text()) for r in (straight, broken))
    assert {k: sa[k] for k in ("rebuilds", "pseudo_steps", "kept")} == {k: sb[k] for k in ("rebuilds", "pseudo_steps", "kept")}
    plain = train(subject, tmp_path / "plain", dataclasses.replace(cfg, augment=None), progress=False)  # the same seed
    p = load_checkpoint(list_checkpoints(plain)[-1])
    assert sa["pseudo_steps"] > 0 and any(not torch.equal(a["model"][k], p["model"][k]) for k in a["model"])


def test_examiner_threshold_drops_candidates_and_training_goes_on(subject, models, tmp_path):
    cfg = TrainConfig(iterations=12, checkpoint_every=12, avatar=TINY_AVATAR,
                      augment=augment_cfg("examined", models, threshold=1.0))  # nothing reaches a score of 1
    run = train(subject, tmp_path / "t", cfg, progress=False)
    summary = json.loads((run / AUGMENT_JSON).read_text())
    assert summary["kept"] == 0 and summary["dropped"] == 2 and summary["pseudo_steps"] == 0  # both tried, both dropped
    assert np.all(np.isfinite(losses(run)))


def test_the_shipped_models_are_the_default_and_none_turns_them_off():
    from trioman.runtime.pretrained import shipped_path

    refiner, examiner = str(shipped_path("refiner")), str(shipped_path("examiner"))
    cfg = AugmentConfig(mode="examined")
    assert (cfg.mode, cfg.refiner, cfg.examiner, cfg.keep_carried, cfg.candidates) == ("examined", refiner, examiner, True, 2)
    assert (AugmentConfig(mode="refined").refiner, AugmentConfig(mode="refined").examiner) == (refiner, None)
    assert AugmentConfig(mode="examined", refiner="r").examiner == examiner
    cfg = AugmentConfig(mode="examined", examiner="none")
    assert (cfg.mode, cfg.refiner, cfg.examiner) == ("refined", refiner, None)
    cfg = AugmentConfig(mode="examined", refiner="none")
    assert (cfg.mode, cfg.refiner, cfg.examiner, cfg.keep_carried) == ("aligned", None, None, False)
    assert AugmentConfig(mode="aligned", refiner="none").refiner is None
    with pytest.raises(ValueError, match="^examiner: chooses among refined candidates; `refiner` none"):
        AugmentConfig(mode="examined", refiner="none", examiner="e")


def test_without_shipped_models_a_refiner_must_be_given(tmp_path, monkeypatch):
    from trioman.runtime import pretrained

    monkeypatch.setattr(pretrained, "PRETRAINED_DIR", tmp_path)
    with pytest.raises(ValueError, match="^refiner: the shipped refiner: .*models.json: missing file"):
        AugmentConfig(mode="refined")
    with pytest.raises(ValueError, match="^examiner: the shipped examiner: .*models.json: missing file"):
        AugmentConfig(mode="examined", refiner="r")
    assert AugmentConfig(mode="examined", refiner="r", examiner="e").examiner == "e"


def test_config_errors_name_the_option():
    with pytest.raises(ValueError, match="per_frame: 2 candidates need an Examiner"):
        AugmentConfig(mode="coarse", per_frame=2)
    with pytest.raises(ValueError, match="^share: must lie in \\(0, 1\\]"):
        AugmentConfig(share=0.0)
    with pytest.raises(ValueError, match="^mode: expected one of"):
        AugmentConfig(mode="fancy")
    with pytest.raises(ValueError, match="pose_sigma"):
        AugmentConfig(pose_sigma={"tail": 0.1})
    with pytest.raises(ValueError, match="^detail_sigma: must be a finite number >= 0"):
        AugmentConfig(mode="refined", refiner="r", detail_sigma=-1.0)
    with pytest.raises(ValueError, match="^detail_sigma: needs a Refiner"):
        AugmentConfig(detail_sigma=2.0)
    with pytest.raises(ValueError, match="^align_texture: 0 .* got 8"):
        AugmentConfig(mode="aligned", align_texture=8)
    with pytest.raises(ValueError, match="^align_texture: `mode` coarse takes no colour"):
        AugmentConfig(mode="coarse", align_texture=256)


class _ShiftingRefiner:
    """A Refiner that brightens every pixel by 0.2 and adds a fixed fine pattern (detail)."""

    conditions = "none"

    def refine(self, coarse, reference=None, normal=None):
        pattern = 0.05 * (np.indices(coarse.shape[1:3]).sum(0) % 2)[None, ..., None]
        return np.clip(coarse + 0.2 + pattern, 0, 1)


def test_detail_only_pseudo_frames_keep_the_coarse_colours(subject, models):
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.avatar.model import GaussianAvatar
    from trioman.toolkit.train.augmentation import Augmenter
    from trioman.toolkit.train.data import load_frames

    subj = load_subject(subject)
    frames = load_frames(subj, "train")
    model = GaussianAvatar(subj.body, TINY_AVATAR)
    pools = {}
    for name, kw in (("coarse", {}), ("refined", {"refiner": str(models["refiner"]), "keep_carried": False}),
                     ("detail", {"refiner": str(models["refiner"]), "detail_sigma": 1e3, "keep_carried": False})):
        aug = Augmenter(AugmentConfig(mode="coarse" if name == "coarse" else "refined", pool=3, start=0.0, **kw),
                        subj, frames, 1, seed=0)  # one seed: the same draws in every pool
        if name != "coarse":
            aug.refiner = _ShiftingRefiner()
        aug.rebuild(model)
        pools[name] = np.stack([aug.draw()["images"].numpy() for _ in range(3)])  # the same entries: one rng stream
    shift = {k: np.abs(pools[k].mean((1, 2)) - pools["coarse"].mean((1, 2))).max() for k in ("refined", "detail")}
    assert shift["detail"] < 0.2 * shift["refined"], shift  # a blur wider than the frame removes the mean change
    assert not np.allclose(pools["detail"], pools["coarse"])  # the detail stays


def test_a_pool_frame_is_the_avatar_at_the_rebuild_and_only_drawn_entries_are_made(subject, models):
    from trioman.runtime.formats import load_subject
    from trioman.toolkit.avatar.model import GaussianAvatar
    from trioman.toolkit.train.augmentation import Augmenter
    from trioman.toolkit.train.data import load_frames

    subj = load_subject(subject)
    frames = load_frames(subj, "train")
    cfg = AugmentConfig(mode="aligned", pool=4, start=0.0)
    model = GaussianAvatar(subj.body, TINY_AVATAR)
    now, later = Augmenter(cfg, subj, frames, 10, seed=3), Augmenter(cfg, subj, frames, 10, seed=3)
    now.rebuild(model)
    later.rebuild(model)
    first = now.draw()
    with torch.no_grad():  # training goes on between the rebuild and the draw
        for p in model.parameters():
            p.add_(0.5)
    drawn = later.draw()
    for key in ("images", "masks", "pixel_weights", "poses", "viewmat"):
        torch.testing.assert_close(drawn[key], first[key], rtol=0, atol=0)
    assert later.stats["candidates"] == 1 and later.stats["entries"] == 4  # the other three are still pending
    made_now = [e for e in later.entries if "images" in e]
    assert len(made_now) == 1
    restored = Augmenter(cfg, subj, frames, 10, seed=0)
    restored.load_state_dict(later.state_dict(), model)  # pending entries and the rebuild's avatar come back
    again = [restored.draw() for _ in range(6)]
    expect = [later.draw() for _ in range(6)]
    for a, b in zip(again, expect):
        torch.testing.assert_close(a["images"], b["images"], rtol=0, atol=0)


def test_bad_model_files_give_one_line_errors(models, tmp_path):
    with pytest.raises(ValueError, match=r"^refiner: .*config: unknown Refiner config fields"):
        load_pseudo_refiner(models["examiner"])  # an Examiner given as the Refiner
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"^examiner: .*junk.pt: not a readable checkpoint"):
        load_pseudo_examiner(junk)
    with pytest.raises(FileNotFoundError, match="^refiner: not found"):
        load_pseudo_refiner(tmp_path / "missing")
    (tmp_path / "empty_run").mkdir()
    with pytest.raises(FileNotFoundError, match="^examiner: .*empty_run holds no checkpoint"):
        load_pseudo_examiner(tmp_path / "empty_run")


def test_a_torch_refiner_takes_any_size_padded_to_its_multiple(models):
    """Sides that are not multiples of its total downsampling (16) are padded (edge, bottom and right) and cropped."""
    refiner = load_pseudo_refiner(models["refiner"])
    assert refiner.multiple == 16
    refiner.check_size(24, 40)
    rng = np.random.default_rng(0)
    coarse, ref, normal = (rng.random((2, 24, 40, 3), dtype=np.float32) for _ in range(3))
    got = refiner.refine(coarse, ref, normal)
    padded = [_nchw(np.pad(x, [(0, 0), (0, 8), (0, 8), (0, 0)], mode="edge")) for x in (coarse, ref, normal)]
    with torch.no_grad():
        want = refiner.model(*padded)[:, 0, :, :24, :40].clamp(0, 1).permute(0, 2, 3, 1).numpy()
    assert got.shape == (2, 24, 40, 3) and got.flags.c_contiguous
    np.testing.assert_allclose(got, want, atol=1e-6)
    assert refiner.refine(coarse[:, :16, :32], ref[:, :16, :32], normal[:, :16, :32]).shape == (2, 16, 32, 3)


def _nchw(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def test_onnx_models_load_through_the_same_interface_and_check_the_size(models, tmp_path):
    pytest.importorskip("onnx")
    from tests.runtime.factories import fixed_size_copy
    from trioman.export.onnx_models import export_examiner_onnx, export_refiner_onnx

    export_refiner_onnx(models["refiner"], tmp_path / "r.onnx", size=SIZE)
    export_examiner_onnx(models["examiner"], tmp_path / "e.onnx")
    torch_r, onnx_r = load_pseudo_refiner(models["refiner"]), load_pseudo_refiner(tmp_path / "r.onnx")
    torch_e, onnx_e = load_pseudo_examiner(models["examiner"]), load_pseudo_examiner(tmp_path / "e.onnx")
    rng = np.random.default_rng(0)
    coarse, ref, normal = (rng.random((2, SIZE, SIZE, 3), dtype=np.float32) for _ in range(3))
    np.testing.assert_allclose(onnx_e.score(coarse, ref[0]), torch_e.score(coarse, ref[0]), atol=1e-4)
    # the export size, another multiple of 16, and a size that is not one (both pad it alike)
    for H, W in ((SIZE, SIZE), (48, 64), (24, 40)):
        onnx_r.check_size(H, W)
        coarse, ref, normal = (rng.random((2, H, W, 3), dtype=np.float32) for _ in range(3))
        np.testing.assert_allclose(onnx_r.refine(coarse, ref, normal), torch_r.refine(coarse, ref, normal), atol=1e-3)
    old = load_pseudo_refiner(fixed_size_copy(tmp_path / "r.onnx", tmp_path / "old.onnx"))  # an export without the key
    old.check_size(SIZE, SIZE)
    with pytest.raises(ValueError, match=r"^refiner: .*old.onnx \(Refiner ONNX\) takes 32x32 .* frames are 64x64"):
        old.check_size(64, 64)


@pytest.mark.parametrize("kind", ["torch", "onnx"])
def test_refined_training_at_frames_that_are_not_a_multiple_of_the_refiners(subject, models, tmp_path, kind):
    """image_scale 0.75: 24x24 frames, not a multiple of the Refiner's 16 (nor the ONNX export's size 32)."""
    refiner = models["refiner"]
    if kind == "onnx":
        pytest.importorskip("onnx")
        from trioman.export.onnx_models import export_refiner_onnx

        refiner = tmp_path / "r.onnx"
        export_refiner_onnx(models["refiner"], refiner, size=SIZE, gate_frames=2)
    cfg = TrainConfig(iterations=8, checkpoint_every=8, image_scale=0.75, avatar=TINY_AVATAR,
                      augment=AugmentConfig(mode="refined", refiner=str(refiner), start=0.25, refresh=10, pool=2))
    run = train(subject, tmp_path / "run", cfg, progress=False)
    summary = json.loads((run / AUGMENT_JSON).read_text())
    assert summary["kept"] >= 1 and summary["seconds"]["refine"] > 0 and np.all(np.isfinite(losses(run)))


def test_cli_options_need_augment_and_existing_models(subject, tmp_path, capsys):
    assert main(["train", str(subject), "--out", str(tmp_path / "x"), "--refiner", "r.pt"]) == 1
    assert "--refiner: needs --augment" in capsys.readouterr().err
    assert main(["train", str(subject), "--out", str(tmp_path / "x"), "--augment", "examined", "--refiner", "none",
                 "--examiner", "shipped"]) == 1
    assert "error: --examiner: chooses among refined candidates; --refiner none gives the aligned kind" in capsys.readouterr().err
    assert main(["train", str(subject), "--out", str(tmp_path / "x"), "--augment", "refined", "--refiner",
                 str(tmp_path / "nope.pt")]) == 1
    assert "--refiner: not found" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()  # nothing written before the inputs are checked


def test_augment_alone_means_aligned_with_the_carried_mask_and_a_kind_with_models_the_shipped_ones(subject, tmp_path):
    from trioman.commands.train import augment_config
    from trioman.cli import build_parser
    from trioman.runtime.pretrained import shipped_path

    args = build_parser().parse_args(["train", str(subject), "--out", str(tmp_path / "x"), "--augment"])
    cfg = augment_config(args)
    assert (cfg.mode, cfg.mask, cfg.unknown_weight, cfg.align_sources) == ("aligned", "carried", 0.0, 3)
    assert (cfg.refiner, cfg.examiner) == (None, None)
    args = build_parser().parse_args(["train", str(subject), "--out", str(tmp_path / "x"), "--augment", "examined"])
    assert (augment_config(args).refiner, augment_config(args).examiner) == (str(shipped_path("refiner")),
                                                                             str(shipped_path("examiner")))
    args = build_parser().parse_args(["train", str(subject), "--out", str(tmp_path / "x"), "--augment", "coarse",
                                      "--augment-mask", "alpha", "--augment-sources", "1"])
    assert (augment_config(args).mask, augment_config(args).align_sources) == ("alpha", 1)
    args = build_parser().parse_args(["train", str(subject), "--out", str(tmp_path / "x"), "--augment",
                                      "--augment-texture", "128"])
    assert (augment_config(args).align_texture, cfg.align_texture) == (128, 0)


def test_a_refiner_keeps_the_carried_pixels_unless_told_not_to(subject, tmp_path):
    """--augment refined|examined: keep_carried by default (the measured best); --no-augment-keep-carried turns it off;
    with a kind without a Refiner it is refused by name."""
    from trioman.commands.train import augment_config
    from trioman.cli import build_parser

    ref = tmp_path / "r.onnx"
    ref.write_bytes(b"")
    base = ["train", str(subject), "--out", str(tmp_path / "x")]
    assert augment_config(build_parser().parse_args(base + ["--augment", "refined", "--refiner", str(ref)])).keep_carried
    assert not augment_config(build_parser().parse_args(
        base + ["--augment", "refined", "--refiner", str(ref), "--no-augment-keep-carried"])).keep_carried
    assert not augment_config(build_parser().parse_args(base + ["--augment"])).keep_carried
    assert augment_config(build_parser().parse_args(base + ["--augment", "refined"])).keep_carried  # the shipped Refiner
    with pytest.raises(ValueError, match="^keep_carried: needs a Refiner"):
        augment_config(build_parser().parse_args(base + ["--augment", "aligned", "--augment-keep-carried"]))
