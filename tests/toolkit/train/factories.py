"""The tiny avatar configuration of the training tests. Import it after ``pytest.importorskip("torch")``: the
configuration class comes from the torch avatar model."""

from trioman.toolkit.avatar.model import AvatarConfig

TINY_AVATAR = AvatarConfig(keep=0.3, triplane_channels=4, triplane_res=16, hidden=32)
