"""``trioman export onnx``: the Refiner and the Examiner as ONNX files for the torch-free runtime (``export_onnx``).

The files, their metadata, the checks at export and the sizes: docs/formats.md, "ONNX models"; the rules
behind them: docs/design.md, "Deployment (ONNX)". Modules: ``export`` (the entry points, sizes), ``jobs``
(one model: fp32, int8, fp16 and their checks), ``graph`` (tracing and the ONNX protobuf), ``frames``
(calibration and gate data), ``checkpoints`` (the model to export), ``constants`` and ``errors``.
"""

from trioman.export.config import VARIANTS
from trioman.export.onnx_models.constants import (
    EXAMINER_ATOL,
    INT8_MAX_PSNR_DROP_DB,
    INT8_MIN_AGREEMENT,
    REFINER_ATOL,
)
from trioman.export.onnx_models.errors import ExportError, ExportParityError
from trioman.export.onnx_models.export import (
    export_examiner_onnx,
    export_onnx,
    export_refiner_onnx,
    file_name,
    refiner_export_size,
    summary_lines,
)
from trioman.export.onnx_models.frames import refiner_frames_per_batch, synthetic_frames
from trioman.export.onnx_models.graph import check_dims

__all__ = [
    "EXAMINER_ATOL",
    "ExportError",
    "ExportParityError",
    "INT8_MAX_PSNR_DROP_DB",
    "INT8_MIN_AGREEMENT",
    "REFINER_ATOL",
    "VARIANTS",
    "check_dims",
    "export_examiner_onnx",
    "export_onnx",
    "export_refiner_onnx",
    "file_name",
    "refiner_export_size",
    "refiner_frames_per_batch",
    "summary_lines",
    "synthetic_frames",
]
