"""One module per ``trioman`` subcommand, named after it (``synth-corpus`` -> ``synth_corpus``,
``import`` -> ``import_``): ``add_arguments(parser)`` and ``run(args) -> int``, argument parsing and the
call into the library only. Standard-library imports only at module level (trioman/cli.py)."""


def command_line(name: str, add_arguments, values: dict) -> str:
    """The ``trioman NAME ...`` command that gives ``values`` ({dest: value}) to a subcommand's options:
    positionals and required options always, other options only where they differ from their default (a repeated
    option once per item)."""
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
            flag = action.option_strings[-1]
            if isinstance(action, argparse._AppendAction):  # one item per flag
                words += [word for item in value for word in (flag, str(item))]
            elif isinstance(value, (list, tuple)):
                words += [flag, *map(str, value)]
            elif value is not None:
                words += [flag, str(value)]
    return shlex.join(words)
