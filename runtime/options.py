"""Options declared once, on the fields of the config they set (docs/design.md, "Options").

A config's field that a command exposes carries an :class:`Option` in its metadata (``field = option(default,
help=...)``): its flag, help, metavar, choices and check. From it come the flags a library error's field names are
shown with (:func:`flags`) and the field's check (:func:`check_options`, called by the config's ``__post_init__``);
``trioman/options.py`` makes the command's argparse options and reads back what a user gave. A library default and
its command's default are then one value. Standard-library imports only: the commands build their parsers from
configs that import this.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import MISSING, dataclass
from typing import Any, Callable, Iterable

Check = Callable[[Any], "str | None"]  # a value -> what is wrong with it (None: nothing)


@dataclass(frozen=True)
class Option:
    help: str
    flag: str | None = None  # as typed; None: "--" and the field's name with dashes
    metavar: str | None = None
    choices: tuple[Any, ...] | None = None
    const: Any = None  # not None: the flag alone (no value) sets this
    check: Check | None = None
    default_text: str | None = None  # the default as the help says it, where the field's value says less
    parse: Callable[[str], Any] | None = None  # the text typed -> the value (an item's, for a tuple; None: the type's)
    repeat: bool = False  # a tuple field: one item per flag (``--ply-frame 1 --ply-frame 4``)
    sep: str | None = None  # a tuple field: its items in one word, split on this (``--variants fp32,int8``)


def option(default: Any = MISSING, *, help: str, flag: str | None = None, metavar: str | None = None,
           choices: Iterable[Any] | None = None, const: Any = None, check: Check | None = None,
           default_text: str | None = None, parse: Callable[[str], Any] | None = None, repeat: bool = False,
           sep: str | None = None) -> Any:
    """A dataclass field with its option: ``name: float = option(0.2, help="...", check=number(0, 1))``. No default:
    the option is required. A ``tuple[T, ...]`` field takes its items after one flag (``--calibration A B``), one per
    flag (``repeat``) or in one word split on ``sep``; ``choices`` and ``check`` then hold for each item."""
    spec = Option(help, flag, metavar, None if choices is None else tuple(choices), const, check, default_text, parse,
                  repeat, sep)
    return dataclasses.field(default=default, metadata={"option": spec})


def declared(cls: type) -> list[tuple[dataclasses.Field, Option]]:
    """The fields of dataclass ``cls`` that carry an option, in declaration order."""
    return [(f, f.metadata["option"]) for f in dataclasses.fields(cls) if "option" in f.metadata]


def flag_of(f: dataclasses.Field, spec: Option) -> str:
    return spec.flag or "--" + f.name.replace("_", "-")


def flags(*classes: type) -> dict[str, str]:
    """Field name -> flag as typed, over the options of ``classes`` (a library error names fields, a command's
    user reads flags)."""
    return {f.name: flag_of(f, spec) for cls in classes for f, spec in declared(cls)}


def base_type(f: dataclasses.Field) -> str:
    """The field's annotation without ``| None`` ("float | None" -> "float")."""
    parts = [p.strip() for p in str(f.type).split("|")]
    return next((p for p in parts if p != "None"), "None")


def item_type(f: dataclasses.Field) -> str | None:
    """The item type of a ``tuple[T, ...]`` field ("tuple[int, ...]" -> "int"), None for any other field."""
    kind = base_type(f)
    return kind[len("tuple["):-len(", ...]")] if kind.startswith("tuple[") and kind.endswith(", ...]") else None


def _optional(f: dataclasses.Field) -> bool:
    return "None" in [p.strip() for p in str(f.type).split("|")]


def shown(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def check_options(obj: Any) -> None:
    """Check each declared field of dataclass instance ``obj``: its choices and its check, a ValueError naming the
    field and the value (``start: must lie in [0, 1), got 2.0``; a tuple field's, each item). None passes where the
    field may be None."""
    for f, spec in declared(type(obj)):
        value = getattr(obj, f.name)
        if value is None and _optional(f):
            continue
        if item_type(f) is None:
            _check_value(f, spec, value)
        elif not isinstance(value, tuple):
            raise ValueError(f"{f.name}: must be a tuple, got {value!r}")
        else:
            for item in value:
                _check_value(f, spec, item)


def _check_value(f: dataclasses.Field, spec: Option, value: Any) -> None:
    """``value``, the field's or one item of a tuple field's, against the field's choices, type and check."""
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f"{f.name}: expected one of {', '.join(map(str, spec.choices))}, got {value!r}")
    if base_type(f) == "bool" and not isinstance(value, bool):
        raise ValueError(f"{f.name}: must be true or false, got {value!r}")
    problem = spec.check(value) if spec.check is not None else None
    if problem is not None:
        raise ValueError(f"{f.name}: {problem}, got {value!r}")


def integer(lo: int | None = None, hi: int | None = None) -> Check:
    """A check: an integer (not a bool; numpy's too) in [lo, hi]."""
    def check(value: Any) -> str | None:
        ok = isinstance(value, numbers.Integral) and not isinstance(value, bool) and (lo is None or value >= lo) \
            and (hi is None or value <= hi)
        if ok:
            return None
        if hi is None:
            return "must be an integer" + ("" if lo is None else f" >= {lo}")
        return f"must be an integer in [{lo}, {hi}]"
    return check


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False) -> Check:
    """A check: a finite real number (not a bool) in the interval from lo to hi (open ends as asked)."""
    def check(value: Any) -> str | None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        ok = ok and (lo is None or (value > lo if lo_open else value >= lo))
        ok = ok and (hi is None or (value < hi if hi_open else value <= hi))
        if ok:
            return None
        if hi is None:
            return "must be a finite number" + ("" if lo is None else f" {'>' if lo_open else '>='} {shown(lo)}")
        return f"must lie in {'(' if lo_open else '['}{shown(lo)}, {shown(hi)}{')' if hi_open else ']'}"
    return check
