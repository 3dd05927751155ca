"""The ONNX graph: tracing, dims, node order, metadata and saving (external data above 2 GiB)."""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any, Mapping, Sequence

import onnx
import torch
from torch import nn

from trioman.export.onnx_models.constants import BATCH_AXIS, OPSET
from trioman.export.onnx_models.errors import ExportError
from trioman.runtime import onnx_models as rt
from trioman.runtime.outputs import fsync_file, write_synced


def _dims(value_info: Any) -> list[int | str | None]:
    out = []
    for d in value_info.type.tensor_type.shape.dim:
        out.append(d.dim_value if d.HasField("dim_value") else (d.dim_param or None))
    return out


def check_dims(proto: onnx.ModelProto, inputs: Sequence[str], outputs: Sequence[str], input_tail: Sequence[int | str],
               output_tail: Sequence[int | str], where: str) -> None:
    """Input and output names, dim 0 symbolic ("batch"), the other dims as the tails say: an int a static dim of
    that size, a str a symbolic dim of that name (the Refiner's "height" and "width")."""
    got_in = [i.name for i in proto.graph.input]
    got_out = [o.name for o in proto.graph.output]
    if got_in != list(inputs) or got_out != list(outputs):
        raise ExportError(f"{where}: graph inputs/outputs {got_in} / {got_out}, expected {list(inputs)} / {list(outputs)}")
    for v, tail in [(i, input_tail) for i in proto.graph.input] + [(o, output_tail) for o in proto.graph.output]:
        dims = _dims(v)
        if len(dims) != 1 + len(tail) or isinstance(dims[0], int) or dims[0] is None or list(dims[1:]) != list(tail):
            symbolic = [BATCH_AXIS] + [d for d in tail if isinstance(d, str)]
            raise ExportError(f"{where}: {v.name!r} exported with dims {dims}, expected {[BATCH_AXIS, *tail]} "
                              f"(symbolic {', '.join(symbolic)}; static rest)")


def pin_output_dims(proto: onnx.ModelProto, symbolic: Mapping[str, Mapping[int, str]]) -> None:
    """The outputs' dims named in ``symbolic`` (output name -> {axis: name}, as the export's dynamic axes) get
    those names; the others, but for the batch, are made static where ONNX shape inference proves them (the legacy
    exporter declares every output dim of a dynamic-axes graph symbolic, e.g. 'Transposerefined_dim_1')."""
    inferred = onnx.shape_inference.infer_shapes(proto, strict_mode=True, data_prop=True)
    shapes = {o.name: o.type.tensor_type.shape.dim for o in inferred.graph.output}
    for o in proto.graph.output:
        named = symbolic.get(o.name, {})
        for j, d in enumerate(o.type.tensor_type.shape.dim):
            if j in named:
                d.dim_param = named[j]  # clears dim_value (a oneof)
                continue
            if j == 0 or d.HasField("dim_value"):
                continue
            got = shapes.get(o.name)
            if got is not None and j < len(got) and got[j].HasField("dim_value"):
                d.dim_value = got[j].dim_value  # clears dim_param (a oneof)


def sort_nodes(proto: onnx.ModelProto) -> None:
    """Order the main graph's nodes topologically (onnxruntime's fp16 converter appends its input casts
    at the end, which onnxruntime accepts but the ONNX checker does not)."""
    nodes = list(proto.graph.node)
    producer = {out: i for i, n in enumerate(nodes) for out in n.output if out}
    done: set[int] = set()
    order: list[int] = []
    for start in range(len(nodes)):
        stack = [(start, False)]
        while stack:
            i, expanded = stack.pop()
            if i in done:
                continue
            if expanded:
                done.add(i)
                order.append(i)
                continue
            stack.append((i, True))
            stack.extend((producer[x], False) for x in nodes[i].input if x in producer and producer[x] not in done)
    if order != list(range(len(nodes))):
        del proto.graph.node[:]
        proto.graph.node.extend(nodes[i] for i in order)


def set_metadata(proto: onnx.ModelProto, meta: dict[str, str]) -> None:
    """Replace the model's ``trioman.*`` metadata_props by ``meta`` (keys with the prefix)."""
    keep = [(p.key, p.value) for p in proto.metadata_props if not p.key.startswith(rt.META_PREFIX)]
    del proto.metadata_props[:]
    for key, value in keep + sorted(meta.items()):
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, str(value)


def torch_export(model: nn.Module, example: tuple[torch.Tensor, ...], inputs: Sequence[str],
                  outputs: Sequence[str], scratch: Path | None = None,
                  axes: Mapping[str, Mapping[int, str]] | None = None) -> onnx.ModelProto:
    """The traced graph; with ``scratch`` (a folder), traced into a file there (the exporter then writes a
    model over 2 GiB as external data) and read back with its weights, for ``save_proto(..., external=True)``.
    ``axes``: the symbolic dims per input and output name ({axis: name}); by default the batch (dim 0) alone."""
    if axes is None:
        axes = {n: {0: BATCH_AXIS} for n in list(inputs) + list(outputs)}
    target: Any = io.BytesIO() if scratch is None else str(scratch / "trace.onnx")
    # no autograd: the trace would keep every activation for a backward pass (the same graph either way)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation notice and tracer warnings
        torch.onnx.export(
            model, example, target, input_names=list(inputs), output_names=list(outputs), opset_version=OPSET,
            dynamic_axes={n: dict(a) for n, a in axes.items()}, dynamo=False,
        )
    return onnx.load_from_string(target.getvalue()) if scratch is None else onnx.load(target)


def external_data_path(path: Path) -> Path:
    """The weights file beside a model saved with external data: ``<name>.onnx.data``."""
    return path.with_name(path.name + ".data")


def save_proto(proto: onnx.ModelProto, path: Path, external: bool = False) -> None:
    """Write ``proto``; ``external`` puts every tensor over 1 KiB into ``external_data_path(path)`` (one file,
    read by onnxruntime from the same folder), for models over protobuf's 2 GiB."""
    if external:
        onnx.save_model(proto, str(path), save_as_external_data=True, all_tensors_to_one_file=True,
                        location=external_data_path(path).name, size_threshold=1024)
        for p in (path, external_data_path(path)):
            fsync_file(p)
    else:
        write_synced(path, proto.SerializeToString())
