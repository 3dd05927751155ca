"""Benchmarks: the layer above export (it may import runtime, toolkit and export; nothing
imports it but the commands). One module per ``trioman bench`` target (synth, train, render, models,
deploy, ablation (a package), frames, stability), the raster timings the train target reports, ``scenes`` (the
renderer tests' and the stability report's scenes), ``config`` and
``ablation_config``: the targets' configs, whose fields are the command's options (standard library only), and
``common``: the machine line, timing, peak memory and the report files."""
