"""ONNX smoke test: legacy exporter, opset 17, dynamic batch, parity with torch under onnxruntime."""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest
import torch

from tests.toolkit.examiner.helpers import TINY
from trioman.toolkit.examiner import create_examiner, export_inputs

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


@pytest.mark.parametrize("detail_gain", [0.0, 8.0])
def test_exported_examiner_matches_torch_on_another_batch_size(detail_gain):
    torch.manual_seed(0)
    model = create_examiner(TINY, exportable=True, detail_gain=detail_gain).eval()
    with torch.no_grad():  # move the heads off their init so the score is not ~0.5 everywhere
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # dynamo=False is deprecated, on purpose
        torch.onnx.export(
            model,
            export_inputs(model, batch=2),  # trace with batch >= 2
            buffer,
            opset_version=17,
            dynamo=False,
            input_names=["candidate", "reference"],
            output_names=["score"],
            dynamic_axes={"candidate": {0: "batch"}, "reference": {0: "batch"}, "score": {0: "batch"}},
        )
    proto = onnx.load_from_string(buffer.getvalue())
    onnx.checker.check_model(proto, full_check=True)
    ops = {node.op_type for node in proto.graph.node}
    assert "LayerNormalization" in ops and "Softmax" in ops
    session = ort.InferenceSession(buffer.getvalue(), providers=["CPUExecutionProvider"])
    assert [i.shape for i in session.get_inputs()] == [["batch", 3, 32, 32]] * 2
    assert session.get_outputs()[0].shape == ["batch"]

    candidate, reference = export_inputs(model, batch=3, seed=7)
    (score,) = session.run(None, {"candidate": candidate.numpy(), "reference": reference.numpy()})
    with torch.no_grad():
        expected = model(candidate, reference).numpy()
    assert score.shape == (3,) and expected.std() > 1e-3
    assert np.abs(score - expected).max() <= 1e-4
