"""trioman.export: torch -> ONNX and checkpoint -> portable avatar files (later issues)."""
