"""The fake SMPL-X model (tests/toolkit/body) for the importer tests."""

from tests.toolkit.body.conftest import smplx_model_dir  # noqa: F401  (the session fixture)
