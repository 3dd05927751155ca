"""ONNX smoke test: trace with batch 2 (opset 17, dynamic batch), run batch 3 in onnxruntime."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from tests.toolkit.refiner.helpers import open_zero_inits, tiny_config
from trioman.toolkit.refiner import OUTPUT_NAME, create_refiner, export_inputs

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")


@pytest.mark.parametrize("conditions", ["none", "tex+geo"])
def test_onnx_export_matches_torch_on_another_batch_size(tmp_path, conditions):
    model = open_zero_inits(create_refiner(tiny_config(conditions=conditions), exportable=True)).eval()
    names = list(model.input_names)
    path = tmp_path / "refiner.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(
            model,
            export_inputs(model, batch=2),
            str(path),
            input_names=names,
            output_names=[OUTPUT_NAME],
            opset_version=17,
            dynamic_axes={n: {0: "batch"} for n in names + [OUTPUT_NAME]},
            dynamo=False,
        )
    graph = onnx.load(str(path)).graph
    assert [i.type.tensor_type.shape.dim[0].dim_param for i in graph.input] == ["batch"] * len(names)
    assert graph.output[0].type.tensor_type.shape.dim[0].dim_param == "batch"

    x = export_inputs(model, batch=3, seed=1)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {n: t.numpy() for n, t in zip(names, x)})
    with torch.no_grad():
        want = model(*x).numpy()
    assert got.shape == want.shape == (3, len(names), 3, 32, 32)
    assert np.abs(got - want).max() <= 1e-3
