"""TrioMan: Gaussian human avatars from monocular video with Generator-Refiner-Examiner augmentation.

Import names: ``trioman.runtime`` (numpy + onnxruntime + OpenCV, never torch),
``trioman.toolkit`` (torch training stack) and ``trioman.export`` (torch -> ONNX / portable files).
"""

__version__ = "0.1.0"
