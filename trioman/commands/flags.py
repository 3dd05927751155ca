"""A library error as a command's user reads it (docs/design.md, "Errors name what the caller gave").

A library's error starts with the name of its parameter (``size: must lie in ...``; ``motion walk: ...`` with
the value; ``resume and overwrite: ...``) and puts other parameters it mentions in backquotes (``give
`refiner` too``). A command module declares ``FLAGS``, its parameters -> its flags as typed, and trioman/cli.py
shows every error of ours through :func:`flag_message` with them. Standard-library imports only.
"""

from __future__ import annotations

import re
from typing import Mapping

# Commands whose modules declare no FLAGS of their own: the parameters their library errors name -> the flags.
UNDECLARED = {
    "train": {"run": "--out", "image_scale": "--image-scale", "refine_poses": "--refine-poses", "extra_frames": "--extra-frames",
              "extra_weight": "--extra-weight", "resume": "--resume", "extend_iterations": "--extend-iterations",
              "augment": "--augment", "refiner": "--refiner", "examiner": "--examiner",
              "per_frame": "--per-frame", "threshold": "--threshold", "augment_start": "--augment-start",
              "augment_refresh": "--augment-refresh", "augment_pool": "--augment-pool", "augment_share": "--augment-share",
              "augment_weight": "--augment-weight", "augment_detail_sigma": "--augment-detail-sigma",
              "augment_mask": "--augment-mask", "augment_align_sources": "--augment-sources",
              "augment_align_texture": "--augment-texture",
              "augment_keep_carried": "--augment-keep-carried", "keep_carried": "--augment-keep-carried",
              "unknown_weight": "--augment-unknown-weight"},
}


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


def command_flags(command: str, module) -> Mapping[str, str]:
    """The flags a command's errors are shown with: its module's ``FLAGS``, else ``UNDECLARED``'s entry."""
    return getattr(module, "FLAGS", None) or UNDECLARED.get(command, {})


def shown_message(err: BaseException, message: str, flags: Mapping[str, str]) -> str:
    """What the user reads of ``err`` (already turned into ``message``): a ValueError, or an OSError of ours
    (no errno; the system's name a path, not a parameter), with its names as flags."""
    if flags and isinstance(err, (ValueError, OSError)) and getattr(err, "errno", None) is None:
        return flag_message(message, flags)
    return message
