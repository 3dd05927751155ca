"""trioman.export: torch -> ONNX (Refiner, Examiner) and checkpoint -> portable avatar folder."""
