"""``trioman export onnx``: the Refiner and the Examiner as ONNX files for the torch-free runtime.

    export_onnx(refiner=CKPT, examiner=CKPT, out=DIR, variants=("fp32", "int8", "fp16"), calibration=[npz, ...])

writes, into a temporary sibling folder renamed onto ``out`` at the end (an error leaves nothing):

    refiner.onnx / examiner.onnx              fp32, traced with batch 2, symbolic batch axis "batch", opset 17
    refiner.int8.onnx                         static QDQ, per-channel QInt8 weights, QUInt8 activations
    examiner.int8.onnx                        dynamic int8 of the weight MatMul/Gemm (never Conv: ConvInteger
                                              has no CPU kernel)
    refiner.fp16.onnx / examiner.fp16.onnx    fp16 weights and maths, fp32 I/O; a GPU artifact (no speed on CPU)
    export.json                               per file: precision, bytes, sha256, parity vs torch, gates, seconds

Every file carries the ``trioman.*`` metadata that ``trioman.runtime.models`` requires (docs/formats.md,
"ONNX models"). Checks, in order (docs/design.md, "Deployment (ONNX)"):

- the exported dims: dim 0 of every input and of the output symbolic, the rest static (= the input size);
- ``onnx.checker.check_model(full_check=True)``;
- fp32 parity, torch vs onnxruntime (through the runtime's own loader) at batch 1 and 3 on random
  inputs and on real triplet frames when calibration data is given: Refiner image atol 1e-3, Examiner
  score atol 1e-4. Beyond it -> ``ExportParityError`` and nothing is written;
- int8 task gates on held-out frames (the triplets' test split when there is one): the Refiner's
  refined-vs-GT PSNR within 0.3 dB of fp32's, the Examiner's keep/drop decisions (choice between the
  coarse render and the real frame; score >= 0.5) agreeing with fp32's on >= 98%. A variant that fails
  is not written and is reported as REJECTED with its numbers;
- fp16: parity vs torch recorded (no gate; rejected only if it produces NaN/Inf).

The traced Refiner is an exportable copy whose GroupNorms subtract each group's mean first (the same
function; onnxruntime's InstanceNormalization kernel, which the GroupNorm export goes through, computes
the variance in one pass and loses precision on uncentred groups).

Sizes: the Refiner is convolutional and trained on crops, so its export size is ``size`` if given,
else the calibration triplets' frame size, else its config's ``image_size`` (a multiple of its total
downsampling). The Examiner's size is its config's ``img_size``; calibration frames of another size
are resized with cv2.INTER_AREA (as ``ExaminerModel.score`` does).

Modules: ``export`` (the entry points, sizes), ``jobs`` (one model: fp32, int8, fp16 and their checks),
``graph`` (tracing and the ONNX protobuf), ``frames`` (calibration and gate data), ``checkpoints`` (the model
to export), ``constants`` and ``errors``.
"""

from trioman.export.onnx_models.constants import (
    EXAMINER_ATOL,
    INT8_MAX_PSNR_DROP_DB,
    INT8_MIN_AGREEMENT,
    REFINER_ATOL,
    VARIANTS,
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
