"""One module per ``trioman`` subcommand, named after it (``synth-corpus`` -> ``synth_corpus``,
``import`` -> ``import_``): ``add_arguments(parser)`` and ``run(args) -> int``, argument parsing and the
call into the library only. Standard-library imports only at module level (trioman/cli.py)."""
