"""``trioman render``: one-line refusals for a non-finite camera and an image that shows nothing (issue 18, cases 7, 8)."""

from __future__ import annotations

from tests.runtime.test_animate import _transparent, avatar_dir  # noqa: F401 (fixture)
from trioman.cli import main
from trioman.runtime.image_io import read_png


def render(avatar_dir, out, *args) -> int:  # noqa: F811
    return main(["render", str(avatar_dir), "--out", str(out), "--size", "32", *args])


def test_a_non_finite_camera_is_named_as_such(avatar_dir, tmp_path, capsys):  # noqa: F811
    # it used to say that the eye coincides with the target
    assert render(avatar_dir, tmp_path / "x.png", "--camera", "nan,0") == 1
    assert "--camera: AZ,EL must be finite degrees, got 'nan,0'" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_an_image_that_shows_nothing_is_refused(avatar_dir, tmp_path, capsys):  # noqa: F811
    assert render(avatar_dir, tmp_path / "x.png") == 0
    assert (read_png(tmp_path / "x.png") < 0.8).any()
    _transparent(avatar_dir)
    assert render(avatar_dir, tmp_path / "y.png") == 1
    assert "--camera front: the image shows nothing of the avatar (out of view); not written" in capsys.readouterr().err
    assert not (tmp_path / "y.png").exists()
