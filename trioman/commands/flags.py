"""A library error as a command's user reads it (docs/design.md, "Errors name what the caller gave").

A library's error starts with the name of its parameter (``size: must lie in ...``; ``motion walk: ...`` with
the value; ``resume and overwrite: ...``) and puts other parameters it mentions in backquotes (``give
`refiner` too``). A command module's ``flags()`` maps them to its flags as typed (made from the options declared on
its configs' fields, trioman/options.py, and its own flags), and trioman/cli.py shows every error of ours through
:func:`flag_message` with them. Standard-library imports only.
"""

from __future__ import annotations

import re
from typing import Mapping

def flag_message(message: str, flags: Mapping[str, str]) -> str:
    """``message`` with the leading parameter name(s) (``name:``, ``name VALUE:``, ``a and b:``) and the
    backquoted ones (`` `name` ``) that ``flags`` holds replaced by their flags; the rest stays as it is."""
    head, sep, rest = message.partition(": ")
    if sep:
        names = head.split(" and ")
        first, space, value = head.partition(" ")
        if all(n in flags for n in names):
            head = " and ".join(flags[n] for n in names)
        elif first in flags:
            head = flags[first] + space + value
    return re.sub(r"`(\w+)`", lambda m: flags.get(m[1], m[0]), head + sep + rest)


def command_flags(module) -> Mapping[str, str]:
    """The flags a command's errors are shown with: its module's ``flags()`` (none without one)."""
    return module.flags() if hasattr(module, "flags") else {}


def shown_message(err: BaseException, message: str, flags: Mapping[str, str]) -> str:
    """What the user reads of ``err`` (already turned into ``message``): a ValueError, or an OSError of ours
    (no errno; the system's name a path, not a parameter), with its names as flags."""
    if flags and isinstance(err, (ValueError, OSError)) and getattr(err, "errno", None) is None:
        return flag_message(message, flags)
    return message
