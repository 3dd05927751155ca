"""``trioman render``: one-line refusals for a non-finite camera and an image that shows nothing (issue 18, cases 7, 8)."""

from __future__ import annotations

from tests.runtime.factories import transparent
from trioman.cli import main
from trioman.runtime.image_io import read_png


def render(avatar_dir, out, *args) -> int:
    return main(["render", str(avatar_dir), "--out", str(out), "--size", "32", *args])


def test_a_non_finite_camera_is_named_as_such(avatar_dir, tmp_path, capsys):
    # it used to say that the eye coincides with the target
    assert render(avatar_dir, tmp_path / "x.png", "--camera", "nan,0") == 1
    assert "--camera: AZ,EL must be finite degrees, got 'nan,0'" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_an_image_that_shows_nothing_is_refused(avatar_dir, tmp_path, capsys):
    assert render(avatar_dir, tmp_path / "x.png") == 0
    assert (read_png(tmp_path / "x.png") < 0.8).any()
    transparent(avatar_dir)
    assert render(avatar_dir, tmp_path / "y.png") == 1
    assert "--camera front: the image shows nothing of the avatar (out of view); not written" in capsys.readouterr().err
    assert not (tmp_path / "y.png").exists()


def test_the_image_never_replaces_or_enters_an_input(avatar_dir, tmp_path, capsys):
    # issue 41, D2: --out AVATAR/gaussians.npz used to leave an avatar that no longer loads
    before = {p.name: p.read_bytes() for p in avatar_dir.iterdir() if p.is_file()}
    target = avatar_dir / "gaussians.npz"
    assert render(avatar_dir, target) == 1
    assert f"--out {target}: lies inside the input {avatar_dir}; write the output outside it" in capsys.readouterr().err
    motion = tmp_path / "m.npz"
    motion.write_bytes(b"not read")
    assert render(avatar_dir, motion, "--pose", f"{motion}@0") == 1
    assert f"--out {motion}: is the input {motion}" in capsys.readouterr().err
    assert motion.read_bytes() == b"not read"
    assert {p.name: p.read_bytes() for p in avatar_dir.iterdir() if p.is_file()} == before


def test_a_size_out_of_range_is_refused_with_its_flag(avatar_dir, tmp_path, capsys):
    # issue 41, U2: --size 0 used to render 512 px
    assert main(["render", str(avatar_dir), "--out", str(tmp_path / "x.png"), "--size", "0"]) == 1
    assert "--size: must lie in [16, 4096] pixels, got 0" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()
