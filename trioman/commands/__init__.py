"""One module per ``trioman`` subcommand, named after it (``synth-corpus`` -> ``synth_corpus``,
``import`` -> ``import_``): ``add_arguments(parser)`` and ``run(args) -> int``, argument parsing and the
call into the library only. Standard-library imports only at module level (trioman/cli.py)."""


def command_line(name: str, add_arguments, values: dict) -> str:
    """The ``trioman NAME ...`` command that gives ``values`` ({dest: value}) to a subcommand's options:
    positionals and required options always, other options only where they differ from their default."""
    import argparse
    import shlex

    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    words = ["trioman", name]
    for action in parser._actions:
        value = values.get(action.dest, action.default)
        if not action.option_strings:
            words.append(str(value))
        elif isinstance(action, argparse._StoreTrueAction):
            words += [action.option_strings[-1]] if value else []
        elif action.required or value != action.default:
            if isinstance(value, list):
                words += [action.option_strings[-1], *map(str, value)]
            elif value is not None:
                words += [action.option_strings[-1], str(value)]
    return shlex.join(words)
