"""Tolerances, gates, opset and file names of the ONNX export (docs/design.md, "Deployment (ONNX)")."""

from trioman.runtime.outputs import FolderKind, known_kind

OPSET = 17
EXPORTER = "torch.onnx.export, TorchScript (legacy) exporter, dynamo=False"
TRACE_BATCH = 2  # trace with batch >= 2 (a traced size-1 batch may be specialised)
PARITY_BATCHES = (1, 3)  # other batch sizes than the traced one
BATCH_AXIS = "batch"
HEIGHT_AXIS, WIDTH_AXIS = "height", "width"  # the Refiner's symbolic image size (its graph takes any multiple of its downsampling)
MAX_PROTO_BYTES = 2**31 - 2**24  # one serialised ONNX protobuf is below 2 GiB; keep 16 MiB for the graph itself
REFINER_ATOL = 1e-3  # max |onnxruntime - torch| on refined images (docs/design.md, Deployment)
EXAMINER_ATOL = 1e-4  # on Examiner scores
INT8_MAX_PSNR_DROP_DB = 0.3  # Refiner int8 gate: refined-vs-GT PSNR within this of fp32's
INT8_MIN_AGREEMENT = 0.98  # Examiner int8 gate: keep/drop decisions agreeing with fp32's
KEEP_THRESHOLD = 0.5  # the Examiner decision threshold the gate checks
VARIANT_PARITY_FRAMES = 8  # int8/fp16 parity with torch (informative, not gated) on this many gate frames
# Refiner frames per batch when the export runs it on frames (calibration, parity, gate): at most
# REFINER_BATCH_PIXELS pixels per image and at most REFINER_MAX_BATCH frames. Its activations grow with
# the pixels of a batch (its cross-view attention with their square per frame); onnxruntime's outputs
# do not depend on the batch, so neither do the calibration ranges nor the gates.
REFINER_BATCH_PIXELS = 256 * 256
REFINER_MAX_BATCH = 8
# Refiner int8: the ops with weights (and the attention MatMuls) only; quantizing every op buys no
# accuracy (docs/findings.md, "ONNX export").
REFINER_INT8_OPS = ("Conv", "MatMul", "Gemm")
EXPORT_JSON = "export.json"
REPORT_FORMAT = "trioman-onnx-export"
# What --overwrite may replace (outputs.check_folder_target): an export folder of exactly these files.
EXPORT_FOLDER = known_kind(FolderKind("ONNX export", EXPORT_JSON, files=(EXPORT_JSON, "refiner*.onnx", "examiner*.onnx",
                                                              "refiner*.onnx.data", "examiner*.onnx.data"), format=REPORT_FORMAT))
# fp16: ops kept in fp32 on top of onnxruntime's default block list (overflow-prone reductions and
# normalisations: LayerNorm/GroupNorm squares, softmax exponentials; Resize as the reference suggests).
FP16_KEEP_FP32 = ("LayerNormalization", "GroupNormalization", "InstanceNormalization", "Softmax", "ReduceMean",
                  "ReduceSum", "Pow", "Sqrt", "Resize", "Log", "Exp")
FP32_NOTE = "reference precision, checked against torch"
FP16_NOTE = "GPU artifact: fp16 brings no speed on onnxruntime's CPU execution provider (it inserts casts)"
