"""The exported avatar rendered by the runtime (numpy FK/LBS + ONNX deltas + numpy splats) against the
checkpoint rendered by the toolkit (torch), and the runtime's animate/render commands without torch."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnx")

from tests.conftest import run_python  # noqa: E402
from trioman.cli import main  # noqa: E402
from trioman.runtime.formats import load_avatar  # noqa: E402
from trioman.runtime.render import rasterize  # noqa: E402


@pytest.fixture(scope="module")
def exported(tiny_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("exported") / "avatar"
    assert main(["export", "avatar", str(tiny_run), "--out", str(out)]) == 0
    return out


def test_runtime_render_matches_the_toolkit_render(tiny_run, exported):
    from trioman.toolkit.evaluate import load_run, render_frame

    model, subject, _, _ = load_run(tiny_run)
    av = load_avatar(exported)
    white = np.ones(3, np.float32)
    worst = 0.0
    for i in range(subject.num_frames):
        ref = render_frame(model, subject, i, torch.ones(3))
        g = av.gaussians(subject.poses[i], subject.trans[i])
        got = rasterize(*g, subject.viewmat[i], subject.K[i], subject.width, subject.height, background=white).rgb
        assert got.shape == ref.shape and (np.abs(got - 1) > 0.05).any(), "the avatar is in view"
        worst = max(worst, float(np.abs(np.clip(got, 0, 1) - ref).max()))
    assert worst <= 1e-4, worst


def test_animate_and_render_without_torch(exported, tmp_path):
    subject_dir = load_avatar(exported).meta["source"]["run"]
    proc = run_python(f"""
        import sys
        from trioman.cli import main
        assert main(['animate', {str(exported)!r}, '--motion', 'jump', '--frames', '4', '--size', '48',
                     '--out', {str(tmp_path / 'a.mp4')!r}, '--frames-dir', {str(tmp_path / 'frames')!r}, '--quiet']) == 0
        assert main(['animate', {str(exported)!r}, '--motion', 'wave', '--frames', '3', '--size', '32', '--camera', 'orbit',
                     '--out', {str(tmp_path / 'b.mp4')!r}, '--quiet']) == 0
        assert main(['render', {str(exported)!r}, '--pose', 'squat@5', '--camera', '45,10', '--size', '40',
                     '--out', {str(tmp_path / 'r.png')!r}]) == 0
        assert 'torch' not in sys.modules or sys.modules['torch'] is None
    """, block_torch=True)
    assert proc.returncode == 0, proc.stderr
    assert "ms/frame" in proc.stdout and "fps" in proc.stdout
    assert (tmp_path / "a.mp4").stat().st_size > 0 and (tmp_path / "b.mp4").stat().st_size > 0
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == [f"{i:05d}.png" for i in range(4)]
    from trioman.runtime.image_io import read_png

    img = read_png(tmp_path / "r.png")
    assert img.shape == (40, 40, 3) and (img < 0.9).any()
    assert subject_dir  # the avatar records its source run


def test_render_with_the_subject_camera_and_bad_specs(exported, tiny_run, tmp_path, capsys):
    from trioman.toolkit.evaluate import load_run

    subject = load_run(tiny_run)[1]
    out = tmp_path / "s.png"
    assert main(["render", str(exported), "--pose", f"{subject.root}@2", "--camera", "subject", "--out", str(out)]) == 0
    from trioman.runtime.image_io import read_png

    assert read_png(out).shape == (subject.height, subject.width, 3)
    for args, msg in [(["--pose", "moonwalk"], "neither a shipped motion"),
                      (["--pose", "wave@x"], "--pose: frame after '@' must be an integer"),
                      (["--pose", "wave@999"], "--pose: frame 999 is out of range"),
                      (["--camera", "subject"], "--camera: 'subject' needs --pose SUBJECT@FRAME"),
                      (["--camera", "up"], "--camera: expected front, subject or AZ,EL"),
                      (["--background", "2,0,0"], "--background: expected three numbers")]:
        assert main(["render", str(exported), "--out", str(tmp_path / "x.png"), *args]) == 1
        assert msg in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
    assert main(["animate", str(exported), "--motion", "walk", "--size", "8", "--out", str(tmp_path / "v.mp4")]) == 1
    assert "--size: must lie in [16, 4096]" in capsys.readouterr().err
