"""The fake SMPL-X model file, written once per session (about 110 MB in the session's temp folder)."""

from __future__ import annotations

import pytest

from tests.toolkit.body.fake_smplx import write_fake_smplx

SKIP_REASON = "needs the 'smplx' extra: pip install 'trioman[smplx]'"


@pytest.fixture(scope="session")
def smplx_model_dir(tmp_path_factory):
    """A folder with SMPLX_MALE.npz and SMPLX_NEUTRAL.npz (the same fake model, random but valid values)."""
    pytest.importorskip("torch")
    pytest.importorskip("smplx", reason=SKIP_REASON)
    folder = tmp_path_factory.mktemp("smplx_models")
    write_fake_smplx(folder / "SMPLX_MALE.npz")
    (folder / "SMPLX_NEUTRAL.npz").symlink_to(folder / "SMPLX_MALE.npz")
    return folder
