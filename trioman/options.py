"""A command's argparse options made from the options declared on its configs' fields (trioman/runtime/options.py):
every option defaults to None ("not given", so the config's own default applies), its help ends with the field's
default, and :func:`given` reads back the fields a user set (docs/design.md, "Options")."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import MISSING
from typing import Any, Iterable, Mapping

from trioman.runtime.options import Option, base_type, declared, flag_of, item_type, shown


def dest_of(f: dataclasses.Field, spec: Option) -> str:
    """The argparse destination of a field's option: its flag's name (``--augment-start`` -> ``augment_start``)."""
    return flag_of(f, spec).lstrip("-").replace("-", "_")


_PARSERS = {"int": int, "float": float, "str": str}


def _typed(parse):
    """A field's parser as argparse's ``type``: its ValueError is the message argparse shows."""
    def typed(text: str):
        try:
            return parse(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    return typed


def _split(parse, sep: str):
    """A parser of items in one word, split on ``sep`` (blank items left out) -> the tuple."""
    def split(text: str) -> tuple:
        return tuple(parse(item.strip()) for item in text.split(sep) if item.strip())
    return split


def help_text(f: dataclasses.Field, spec: Option) -> str:
    """The option's help with the field's default (or ``default_text``), so help cannot disagree with the library."""
    if spec.default_text is not None:
        return f"{spec.help} (default {spec.default_text})"
    if f.default is MISSING or f.default is None or f.default == ():
        return spec.help
    if isinstance(f.default, bool):
        return f"{spec.help} (default {'on' if f.default else 'off'})"
    if isinstance(f.default, tuple):
        return f"{spec.help} (default {(spec.sep or ' ').join(map(shown, f.default))})"
    return f"{spec.help} (default {shown(f.default)})"


def add_options(parser: argparse.ArgumentParser | Any, cls: type, names: Iterable[str] | None = None,
                prefix: str = "") -> None:
    """An argparse option per declared field of ``cls`` (only ``names`` when given; ``prefix`` before each help, e.g.
    "ablation: "). Every option defaults to None, "not given", so the config's own default applies (:func:`given`);
    a field without a default is a required option."""
    wanted = None if names is None else set(names)
    for f, spec in declared(cls):
        if wanted is not None and f.name not in wanted:
            continue
        kw: dict[str, Any] = {"dest": dest_of(f, spec), "default": None, "help": prefix + help_text(f, spec),
                              "required": f.default is MISSING and f.default_factory is MISSING}
        kind = item_type(f) or base_type(f)
        if kind == "bool":
            kw["action"] = argparse.BooleanOptionalAction
        else:
            if kind not in _PARSERS:
                raise TypeError(f"{cls.__name__}.{f.name}: an option needs an int, float, str or bool field (or a tuple "
                                f"of one), not {f.type}")
            parse = _typed(spec.parse) if spec.parse else _PARSERS[kind]
            kw["type"] = parse
            if spec.choices is not None and spec.sep is None:
                kw["choices"] = spec.choices
            if spec.metavar is not None or spec.choices is None:
                kw["metavar"] = spec.metavar or {"int": "N", "float": "X", "str": "TEXT"}[kind]
            if spec.const is not None:
                kw.update(nargs="?", const=spec.const)
            if item_type(f) is not None:  # a tuple: its items in one word, one per flag, or all after the flag
                if spec.sep is not None:
                    kw["type"] = _split(parse, spec.sep)
                elif spec.repeat:
                    kw["action"] = "append"
                else:
                    kw["nargs"] = "+"
        parser.add_argument(flag_of(f, spec), **kw)
    if wanted is not None and wanted - {f.name for f, _ in declared(cls)}:
        raise TypeError(f"{cls.__name__}: no option for {sorted(wanted - {f.name for f, _ in declared(cls)})}")


def given(cls: type, args: argparse.Namespace | Mapping[str, Any], names: Iterable[str] | None = None) -> dict[str, Any]:
    """Field name -> value of the options of ``cls`` that ``args`` sets (not None), ``names`` only when given."""
    values = vars(args) if isinstance(args, argparse.Namespace) else args
    wanted = None if names is None else set(names)
    out = {}
    for f, spec in declared(cls):
        value = values.get(dest_of(f, spec))
        if value is not None and (wanted is None or f.name in wanted):
            out[f.name] = tuple(value) if item_type(f) is not None else value
    return out


