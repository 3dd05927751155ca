"""Options declared on config fields (trioman/runtime/options.py, trioman/options.py): parsers, help, overrides, checks and flags from one spec."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import importlib.util
import math

import pytest
from hypothesis import given as hgiven
from hypothesis import strategies as st

from trioman.cli import COMMANDS
from trioman.options import add_options, given
from trioman.runtime.options import check_options, declared, flag_of, flags, integer, number, option


@dataclasses.dataclass(frozen=True)
class Toy:
    count: int = option(3, check=integer(1), help="how many")
    rate: float = option(0.5, flag="--toy-rate", check=number(0, 1, hi_open=True), help="a share")
    kind: str = option("a", choices=("a", "b"), const="b", help="which")
    on: bool = option(False, help="a switch")
    limit: float | None = option(None, check=number(0), help="optional")
    hidden: int = 7  # no option

    def __post_init__(self) -> None:
        check_options(self)


def _parser(cls=Toy, **kw) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(add_help=False)
    add_options(p, cls, **kw)
    return p


def test_a_parser_from_the_fields_gives_only_what_the_user_typed():
    p = _parser()
    assert given(Toy, p.parse_args([])) == {}
    args = p.parse_args(["--count", "5", "--toy-rate", "0.25", "--kind", "--on", "--limit", "2"])
    assert given(Toy, args) == {"count": 5, "rate": 0.25, "kind": "b", "on": True, "limit": 2.0}
    assert Toy(**given(Toy, args)) == Toy(count=5, rate=0.25, kind="b", on=True, limit=2.0)
    assert given(Toy, p.parse_args(["--no-on"])) == {"on": False}
    assert given(Toy, args, names=("count",)) == {"count": 5}


def test_help_shows_the_fields_defaults():
    helps = {a.dest: a.help for a in _parser()._actions}
    assert helps["count"] == "how many (default 3)"
    assert helps["toy_rate"] == "a share (default 0.5)"
    assert helps["on"] == "a switch (default off)"
    assert helps["limit"] == "optional"  # a None default is not shown


def test_flags_name_the_fields_as_typed():
    assert flags(Toy) == {"count": "--count", "rate": "--toy-rate", "kind": "--kind", "on": "--on", "limit": "--limit"}
    assert [f.name for f, _ in declared(Toy)] == ["count", "rate", "kind", "on", "limit"]


def test_only_the_named_options_and_an_unknown_name_is_a_programming_error():
    p = _parser(names=("count",))
    assert {a.dest for a in p._actions} == {"count"}
    with pytest.raises(TypeError, match="no option for"):
        _parser(names=("nope",))


@pytest.mark.parametrize("kw, message", [
    ({"count": 0}, "count: must be an integer >= 1, got 0"),
    ({"count": True}, "count: must be an integer >= 1, got True"),
    ({"rate": 1.0}, "rate: must lie in [0, 1), got 1.0"),
    ({"rate": float("nan")}, "rate: must lie in [0, 1), got nan"),
    ({"kind": "c"}, "kind: expected one of a, b, got 'c'"),
    ({"on": 1}, "on: must be true or false, got 1"),
    ({"limit": -1.0}, "limit: must be a finite number >= 0, got -1.0"),
])
def test_checks_name_the_field_and_the_value(kw, message):
    with pytest.raises(ValueError) as err:
        Toy(**kw)
    assert str(err.value) == message


@hgiven(st.floats(allow_nan=True, allow_infinity=True))
def test_number_accepts_exactly_the_finite_values_of_its_interval(x):
    ok = number(0, 1, hi_open=True)(x) is None
    assert ok == (math.isfinite(x) and 0 <= x < 1)


@dataclasses.dataclass(frozen=True)
class Lists:
    name: str = option(help="a name")  # no default: a required option
    frames: tuple[int, ...] = option((), flag="--frame", repeat=True, check=integer(0), help="frames")
    files: tuple[str, ...] | None = option(None, metavar="FILE", help="files")
    kinds: tuple[str, ...] = option(("a", "b"), sep=",", choices=("a", "b", "c"), help="kinds")

    def __post_init__(self) -> None:
        check_options(self)


def test_tuple_fields_take_their_items_after_the_flag_once_per_flag_or_split():
    p = _parser(Lists)
    args = p.parse_args(["--frame", "3", "--frame", "1", "--files", "x.npz", "y.npz", "--kinds", "c, a,", "--name", "n"])
    assert given(Lists, args) == {"frames": (3, 1), "files": ("x.npz", "y.npz"), "kinds": ("c", "a"), "name": "n"}
    assert given(Lists, p.parse_args(["--name", "n"])) == {"name": "n"}
    assert Lists("n") == Lists("n", frames=(), files=None, kinds=("a", "b"))
    helps = {a.dest: a.help for a in p._actions}
    assert helps["kinds"] == "kinds (default a,b)" and helps["frame"] == "frames"  # an empty tuple is not shown
    with pytest.raises(SystemExit):
        p.parse_args(["--frame", "x", "--name", "n"])  # each item parsed as the item type


def test_a_command_line_repeats_the_flag_of_each_item_of_a_repeated_option():
    from trioman.commands import command_line

    args = _parser(Lists).parse_args(["--frame", "3", "--frame", "1", "--files", "x.npz", "y.npz", "--name", "n"])
    assert command_line("toy", lambda p: add_options(p, Lists), vars(args)) == \
        "trioman toy --name n --frame 3 --frame 1 --files x.npz y.npz"


def test_a_field_without_a_default_is_a_required_option():
    assert {a.dest for a in _parser(Lists)._actions if a.required} == {"name"}
    with pytest.raises(SystemExit):
        _parser(Lists).parse_args([])


@pytest.mark.parametrize("kw, message", [
    ({"frames": (2, -1)}, "frames: must be an integer >= 0, got -1"),
    ({"kinds": ("a", "d")}, "kinds: expected one of a, b, c, got 'd'"),
    ({"frames": [1]}, "frames: must be a tuple, got [1]"),
])
def test_a_tuple_fields_checks_hold_for_each_item(kw, message):
    with pytest.raises(ValueError) as err:
        Lists("n", **kw)
    assert str(err.value) == message


def _specced(module) -> set[str]:
    """The flags declared on the fields of a command's configs (its module's ``_configs()``)."""
    return {flag_of(f, spec) for cls in module._configs() for f, spec in declared(cls)}


def _flags_of(module, target: str | None = None) -> dict[str, argparse.Action]:
    """A command's options by flag, its sub-parsers' (``export avatar``, ``export onnx``) too; only the sub-parser
    ``target``'s when given."""
    parser = argparse.ArgumentParser(add_help=False)
    module.add_arguments(parser)
    parsers, found = [parser], {}
    while parsers:
        actions = parsers.pop()._actions
        subs = {name: sub for a in actions if isinstance(a, argparse._SubParsersAction) for name, sub in a.choices.items()}
        parsers += [subs[target]] if target in subs else list(subs.values())
        if target is None or not subs:
            found.update({s: a for a in actions for s in a.option_strings
                          if s.startswith("--") and not s.startswith("--no-") and s != "--help"})
    return found


# Flags of a command that are not settings of a config: where the run goes and how it is shown.
COMMAND_OWN = {"train": {"--out", "--resume", "--extend-iterations", "--quiet"},
               "synth": {"--out", "--video", "--overwrite", "--quiet"}, "demo": {"--quiet"},
               "fit": {"--out", "--overwrite", "--quiet"}, "synth-corpus": {"--out", "--quiet", "--shard", "--merge"},
               "train-refiner": {"--corpus", "--triplets", "--out"}, "train-examiner": {"--corpus", "--out"}, "eval": {"--out", "--quiet"},
               "triplets": {"--out", "--quiet"}, "animate": {"--motion", "--out", "--frames-dir", "--quiet"},
               "render": {"--pose", "--out"}, "view": {"--motion", "--subject", "--augmented"},
               "augment": {"--avatar", "--refiner", "--examiner", "--out", "--resume", "--overwrite", "--quiet", "--shard",
                           "--merge"},
               "export": {"--out", "--checkpoint", "--overwrite", "--refiner", "--examiner", "--dest", "--heldout"},
               "import": {"--subject", "--out", "--body-model-dir", "--masks", "--overwrite"}, "bench": {"--out"}}


def test_every_flag_of_a_command_has_a_spec():
    for cmd in COMMANDS:
        module = importlib.import_module(cmd.module)
        missing = set(_flags_of(module)) - _specced(module) - COMMAND_OWN.get(cmd.name, set())
        assert not missing, (cmd.name, sorted(missing))


def test_library_and_command_defaults_are_one_value():
    from trioman.bench.ablation_config import SCHEDULE, AblationPlan
    from trioman.commands.bench import _target_configs
    from trioman.export.config import AvatarExportOptions, OnnxExportOptions
    from trioman.toolkit.train.augment_config import AugmentConfig
    from trioman.toolkit.evaluate_config import EvalOptions
    from trioman.toolkit.corpus_training_options import TrainExaminerOptions, TrainRefinerOptions
    from trioman.runtime.animate import AnimateOptions, RenderOptions
    from trioman.runtime.augment_options import AugmentOptions
    from trioman.runtime.inspect import InspectOptions
    from trioman.runtime.viewer.config import TimingOptions, ViewerConfig
    from trioman.toolkit.importers.options import ExAvatarOptions, SmplxFitsOptions
    from trioman.toolkit.train.config import TrainConfig
    from trioman.toolkit.corpus.triplets_config import TripletsOptions

    for cmd_name, specs in (("train", declared(TrainConfig) + declared(AugmentConfig)),
                            *((f"bench {target}", declared(cls)) for target, cls in _target_configs().items()),
                            ("bench ablation", declared(AblationPlan) + [(f, s) for f, s in declared(AugmentConfig)
                                                                        if f.name in SCHEDULE]),
                            ("train-refiner", declared(TrainRefinerOptions)), ("train-examiner", declared(TrainExaminerOptions)),
                            ("eval", declared(EvalOptions)), ("inspect", declared(InspectOptions)),
                            ("triplets", declared(TripletsOptions)), ("animate", declared(AnimateOptions)),
                            ("render", declared(RenderOptions)), ("view", declared(ViewerConfig) + declared(TimingOptions)),
                            ("augment", declared(AugmentOptions)),
                            ("export avatar", declared(AvatarExportOptions)), ("export onnx", declared(OnnxExportOptions)),
                            ("import exavatar", declared(ExAvatarOptions)), ("import smplx-fits", declared(SmplxFitsOptions))):
        name, _, target = cmd_name.partition(" ")
        actions = _flags_of(importlib.import_module(next(c.module for c in COMMANDS if c.name == name)), target or None)
        for field, spec in specs:
            action = actions.get(flag_of(field, spec))
            if action is None:
                continue  # a config field this command does not expose
            assert action.default is None, (cmd_name, field.name)  # not given: the config's own default applies
            if spec.default_text is None and field.default not in (None, (), dataclasses.MISSING):
                assert action.help.endswith(f"(default {_shown(field.default, spec.sep)})"), (cmd_name, field.name, action.help)
        assert actions, cmd_name


def _defaults_agree(fn, options, names: dict[str, str] | None = None) -> None:
    """Each parameter of ``fn`` with a default that is named as a field of ``options`` (or in ``names``: parameter ->
    field) defaults to that field's default."""
    import inspect

    names = {**{f.name: f.name for f, _ in declared(options)}, **(names or {})}
    params = [p for p in inspect.signature(fn).parameters.values() if p.name in names and p.default is not p.empty]
    for p in params:
        assert p.default == getattr(options, names[p.name]), (fn.__name__, p.name, p.default)
    assert params, fn.__name__


def test_the_runtime_functions_default_to_their_commands_options():
    from trioman.runtime.animate import AnimateOptions, animate
    from trioman.runtime.augment import augment
    from trioman.runtime.augment_options import AugmentOptions
    from trioman.runtime.formats import load_subject
    from trioman.runtime.inspect import InspectOptions

    _defaults_agree(load_subject, InspectOptions)
    _defaults_agree(augment, AugmentOptions)
    _defaults_agree(animate, AnimateOptions)
    if importlib.util.find_spec("viser") is not None:  # the viewer extra
        from trioman.runtime.viewer.app import open_viewer
        from trioman.runtime.viewer.config import ViewerConfig

        _defaults_agree(open_viewer, ViewerConfig)


def test_the_toolkit_functions_default_to_their_commands_options():
    pytest.importorskip("torch")
    from trioman.toolkit.corpus.triplets import build_draw_triplets
    from trioman.toolkit.corpus.triplets_config import TripletsOptions

    _defaults_agree(build_draw_triplets, TripletsOptions)
    from trioman.toolkit.importers.exavatar import BodyConfig, import_exavatar
    from trioman.toolkit.importers.options import ExAvatarOptions, SmplxFitsOptions
    from trioman.toolkit.importers.smplx_fits import import_smplx_fits

    _defaults_agree(BodyConfig, ExAvatarOptions)
    _defaults_agree(import_exavatar, ExAvatarOptions)
    _defaults_agree(import_smplx_fits, SmplxFitsOptions)
    pytest.importorskip("onnx")
    from trioman.export.avatar import export_avatar
    from trioman.export.config import AvatarExportOptions, OnnxExportOptions
    from trioman.export.onnx_models import export_onnx

    _defaults_agree(export_avatar, AvatarExportOptions)
    _defaults_agree(export_onnx, OnnxExportOptions)


def _shown(value, sep: str | None = None) -> str:
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, tuple):
        return (sep or " ").join(map(_shown, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def test_the_ablations_schedule_is_the_trainings_default():
    from trioman.bench.ablation_config import AblationBenchConfig, AblationPlan
    from trioman.cli import build_parser
    from trioman.commands.bench import target_config
    from trioman.toolkit.train.augment_config import AugmentConfig

    plan = AblationPlan()
    assert plan.schedule == AugmentConfig() and AblationBenchConfig().plan == plan
    assert target_config(build_parser().parse_args(["bench", "ablation"])).plan == plan
    aug = AugmentConfig()
    assert {k: plan.record()[k] for k in ("start", "refresh", "pool", "share", "weight", "mask")} == \
        {"start": aug.start, "refresh": aug.refresh, "pool": aug.pool, "share": aug.share, "weight": aug.weight,
         "mask": aug.mask}


def test_keep_carried_is_on_wherever_there_is_a_refiner():
    from trioman.toolkit.train.augment_config import AugmentConfig

    assert AugmentConfig(mode="aligned").keep_carried is False
    assert AugmentConfig(mode="refined", refiner="r.onnx").keep_carried is True
    assert AugmentConfig(mode="refined", refiner="r.onnx", keep_carried=False).keep_carried is False
    assert AugmentConfig.from_dict({"mode": "refined", "refiner": "r.onnx"}).keep_carried is False  # an old record


def test_the_model_training_functions_default_to_their_commands_options():
    import inspect

    pytest.importorskip("torch")
    from trioman.toolkit.corpus_training_options import BACKBONES, REFINER_SIZE_NAMES, TrainExaminerOptions, TrainRefinerOptions
    from trioman.toolkit.corpus.training import REFINER_SIZES, FitConfig, examiner_fit, fit_examiner, fit_refiner, refiner_fit
    from trioman.toolkit.refiner.backbones import registered_backbones

    assert tuple(REFINER_SIZES) == REFINER_SIZE_NAMES and tuple(sorted(BACKBONES)) == registered_backbones()
    refiner, examiner = TrainRefinerOptions(), TrainExaminerOptions()
    names = {"conditions": "conditions", "refiner_size": "size", "backbone": "backbone", "device": "device",
             "mixed_precision": "mixed_precision", "gradient_checkpointing": "gradient_checkpointing", "name": "model",
             "pairing": "pairing", "validation_subjects": "validation_subjects", "validate_every": "validate_every"}
    for fn, options in ((fit_refiner, refiner), (fit_examiner, examiner)):
        for p in inspect.signature(fn).parameters.values():
            if p.name in names:
                assert p.default == getattr(options, names[p.name]), (fn.__name__, p.name)
    assert refiner_fit(refiner) == FitConfig() and examiner_fit(examiner) == FitConfig(lr=3e-4, crop=None)
