"""The errors of the ONNX export."""


class ExportError(ValueError):
    """An export that cannot be made as asked, or whose graph is not what the runtime expects."""


class ExportParityError(ExportError):
    """The fp32 ONNX model differs from the torch model beyond the tolerance (nothing was written)."""
