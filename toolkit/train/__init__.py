"""Avatar training: configs and presets, frame data, atomic checkpoints, the optimisation loop."""
