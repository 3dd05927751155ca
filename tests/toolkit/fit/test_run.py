"""``trioman fit`` end to end at a tiny size: a realistic synthetic subject's video in, a subject out, compared
with its truth; bad input named; the bench target."""

import json

import numpy as np
import pytest

from tests.conftest import skip_without_person_models

pytest.importorskip("torch")
pytest.importorskip("anny")

from trioman.runtime.formats import load_subject  # noqa: E402
from trioman.toolkit.fit.evaluate import compare  # noqa: E402
from trioman.toolkit.fit.fitter import FitConfig  # noqa: E402
from trioman.toolkit.fit.run import FitRunConfig, fit_video  # noqa: E402
from trioman.toolkit.synth.subject import SynthConfig, synthesize_subject  # noqa: E402

skip_without_person_models()

QUICK = FitConfig(keyframes=8, key_iterations=60, all_iterations=40)


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    root = tmp_path_factory.mktemp("fitrun")
    synthesize_subject(SynthConfig(seed=1004, size=256, frames=20, aspect=9 / 16, coverage=0.3, style="realistic",
                                   texture_size=256), root / "truth", progress=False, video=root / "video.mp4", workers=1)
    truth = load_subject(root / "truth")
    fitted = fit_video(root / "video.mp4", root / "fit", FitRunConfig(focal=float(truth.K[0, 0, 0]), test_every=4, fit=QUICK),
                       progress=False, say=lambda line: None)
    return root, truth, fitted


def test_a_video_becomes_a_subject_close_to_its_truth(made):
    root, truth, fitted = made
    report = json.loads((root / "fit" / "fit.json").read_text())
    s = report["summary"]
    assert s["frames_read"] == len(truth.indices("train")) and s["frames_kept"] == fitted.num_frames >= 8
    assert sum(s["dropped"].values()) == s["frames_read"] - s["frames_kept"]
    assert set(fitted.split) == {"train", "test"} and fitted.body_model == "anny"
    assert all(name in truth.frame_names for name in fitted.frame_names)
    for name in ("fit.md", "fit_overlay.png", "fit_overlay.mp4"):
        assert (root / "fit" / name).stat().st_size > 500, name
    scores = compare(fitted, truth)
    assert scores["pa_mpjpe"] < 100.0, scores  # a few iterations at 144 x 256 px; bench fit measures the real size
    assert scores["mask_iou"] > 0.8, scores  # the person model's mask against the true person mask
    assert s["mask_iou_mean"] > 0.5 and s["reprojection_px_mean"] < 8.0, s
    i = 0
    img, mask = fitted.image(i), fitted.mask(i)
    assert img[mask == 0].max() == 0 and img[mask > 0.9].std() > 0.03  # premultiplied by the person mask


def test_tracked_at_the_video_size_written_smaller(made, tmp_path):
    """--track-side 0 --long-side 128: the same fit as at the video's size, the subject and its camera halved."""
    from trioman.runtime.frame_selection import FrameSelection

    root, truth, fitted = made
    cfg = FitRunConfig(selection=FrameSelection(long_side=128), track_side=0, focal=float(truth.K[0, 0, 0]) / 2, test_every=4, fit=QUICK)
    small = fit_video(root / "video.mp4", tmp_path / "small", cfg, progress=False, say=lambda line: None)
    assert (fitted.width, fitted.height, small.width, small.height) == (144, 256, 72, 128)
    assert list(small.frame_names) == list(fitted.frame_names) and list(small.split) == list(fitted.split)
    np.testing.assert_allclose(small.poses, fitted.poses, atol=1e-6)
    np.testing.assert_allclose(small.trans, fitted.trans, atol=1e-6)
    np.testing.assert_allclose(small.K, fitted.K * np.array([0.5, 0.5, 1.0])[None, :, None], rtol=1e-6)
    report = json.loads((tmp_path / "small" / "fit.json").read_text())
    assert report["size"] == [72, 128] and report["track_size"] == [144, 256]
    assert report["camera"]["focal_px"] == pytest.approx(truth.K[0, 0, 0] / 2, rel=1e-4)
    mask, big = small.mask(0), fitted.mask(0)
    assert abs(mask.mean() - big.mean()) < 0.01 and np.abs(mask - big.reshape(128, 2, 72, 2).mean((1, 3))).mean() < 0.02


@pytest.mark.parametrize("long_side, track_side, tracked", [(540, None, 540), (256, None, 540), (1080, None, 1080),
                                                             (0, None, 0), (256, 0, 0), (540, 200, 200)])
def test_the_tracking_size(long_side, track_side, tracked):
    from trioman.runtime.frame_selection import FrameSelection

    cfg = FitRunConfig(selection=FrameSelection(long_side=long_side, every=3), track_side=track_side)
    assert cfg.tracking == FrameSelection(long_side=tracked, every=3)


def test_a_video_of_several_shots(made, tmp_path):
    """--cuts: each shot its own sequence of the subject (and its own motion in the fit)."""
    root, truth, fitted = made
    cut = fitted.num_frames // 2
    shots = fit_video(root / "video.mp4", tmp_path / "shots", FitRunConfig(focal=float(truth.K[0, 0, 0]), test_every=4, cuts=(cut,), fit=QUICK),
                      progress=False, say=lambda line: None)
    index = np.array([int(n) for n in shots.frame_names])
    assert list(shots.sequence) == ["video_shot0" if i < cut else "video_shot1" for i in index]
    assert json.loads((tmp_path / "shots" / "fit.json").read_text())["cuts"] == [cut]
    assert compare(shots, truth)["pa_mpjpe"] < 100.0


def test_the_subject_can_be_replaced_only_with_overwrite(made, tmp_path):
    root, truth, _ = made
    with pytest.raises(FileExistsError, match="overwrite"):
        fit_video(root / "video.mp4", root / "fit", FitRunConfig(fit=QUICK), progress=False, say=lambda line: None)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "thesis.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="thesis.txt"):
        fit_video(root / "video.mp4", tmp_path / "mine", FitRunConfig(fit=QUICK), overwrite=True, progress=False,
                  say=lambda line: None)
    assert (tmp_path / "mine" / "thesis.txt").read_text() == "mine"


def test_a_video_without_a_person_is_one_error(tmp_path):
    from trioman.runtime.image_io import write_video

    rng = np.random.default_rng(0)
    write_video(tmp_path / "empty.mp4", (rng.uniform(0.3, 0.4, (96, 64, 3)).astype(np.float32) for _ in range(4)), fps=30)
    with pytest.raises(ValueError, match=r"empty.mp4: 0 of 4 frames show one whole person .*no_person"):
        fit_video(tmp_path / "empty.mp4", tmp_path / "out", FitRunConfig(fit=QUICK), progress=False, say=lambda line: None)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("kwargs, field", [(dict(focal=10.0, fov_deg=60.0), "focal and fov_deg"), (dict(fov_deg=0.5), "fov_deg"),
                                            (dict(test_every=1), "test_every"), (dict(focal=float("nan")), "focal"),
                                            (dict(cuts=(0,)), "cuts")])
def test_bad_settings_are_named(kwargs, field):
    with pytest.raises(ValueError, match=f"^{field}: "):
        FitRunConfig(**kwargs)


def test_the_command_names_a_missing_video(tmp_path):
    from tests.conftest import run_python

    out = run_python(f"import sys; from trioman.cli import main; sys.exit(main(['fit', {str(tmp_path / 'nope.mp4')!r}, "
                     f"'--out', {str(tmp_path / 's')!r}]))")
    lines = [line for line in out.stderr.splitlines() if line.strip() and not line.startswith("INFO")]
    assert out.returncode != 0 and len(lines) == 1 and "nope.mp4" in lines[0], out.stderr
