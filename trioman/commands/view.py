"""``trioman view AVATAR [--motion M] [--subject S]`` / ``trioman view --augmented DIR``: a web viewer (no torch).

The avatar's Gaussians as splats in the browser (viser), posed live by the runtime: a motion picker,
play/pause, a frame slider, the rest pose, pose-dependent terms on/off and a bend slider per joint
group. ``--subject`` adds the subject's training cameras (click one: its real frame beside the render);
``--augmented`` shows an augment output. The library: trioman.runtime.viewer, whose errors name its parameters
(``port: ...``); trioman/cli.py shows them with ``flags()``. Needs the ``viewer`` extra.
Module contract (trioman/cli.py): standard-library imports only at module level.
"""

from __future__ import annotations

import argparse


def _configs():
    from trioman.runtime.viewer.config import TimingOptions, ViewerConfig

    return ViewerConfig, TimingOptions


def flags() -> dict[str, str]:
    """The fields the library's errors name -> this command's flags."""
    from trioman.runtime.options import flags as option_flags

    return {**option_flags(*_configs()), "avatar": "AVATAR", "motion": "--motion", "subject": "--subject",
            "augmented": "--augmented"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from trioman.options import add_options

    parser.add_argument("avatar", metavar="AVATAR", nargs="?", default=None,
                        help="avatar folder (trioman export avatar); with --augmented, default: the run's avatar")
    parser.add_argument("--motion", default=None,
                        help="the motion shown first: a shipped motion (walk, wave, squat, turn, jump, step, arms_raised), "
                             "a motion .npz file or a subject folder (its test poses); all shipped motions stay in the picker")
    parser.add_argument("--subject", default=None,
                        help="subject folder: its training cameras as frustums (click one: real frame beside the render) "
                             "and its test poses in the motion picker")
    parser.add_argument("--augmented", default=None, metavar="DIR",
                        help="a trioman augment output: source frames, candidates, refined frames, Examiner scores")
    for config in _configs():
        add_options(parser, config)


def run(args: argparse.Namespace) -> int:
    import threading

    from trioman.options import given
    from trioman.runtime.viewer.app import open_viewer
    from trioman.runtime.viewer.server import is_local_only

    viewer_config, timing_options = _configs()
    cfg, timing = viewer_config(**given(viewer_config, args)), timing_options(**given(timing_options, args))
    viewer = open_viewer(args.avatar, motion=args.motion, subject=args.subject, augmented=args.augmented,
                         host=cfg.host, port=cfg.port, fps=cfg.fps)
    try:
        avatar = viewer.poser.avatar
        if not is_local_only(cfg.host):
            print(f"view: note: --host {cfg.host} serves the avatar (and any --subject or --augmented frames) to "
                  f"everyone who can reach this machine on the network; the default 127.0.0.1 keeps it to this "
                  f"machine", flush=True)
        if timing.updates is not None:
            t = viewer.time_updates(timing.updates)
            print(f"view: {avatar.num_gaussians:,} Gaussians ({'with' if avatar.pose_dependent else 'no'} pose-dependent "
                  f"terms), {timing.updates} updates of {viewer.poser.name!r}: {t['total_ms']:.1f} ms a pose update "
                  f"(median; posing {t['pose_ms']:.1f}, packing and queueing {t['send_ms']:.1f})")
            return 0
        print(f"view: {avatar.num_gaussians:,} Gaussians of {avatar.root}, motion {viewer.poser.name!r}; "
              f"{viewer.last_update['pose_ms']:.0f} ms a pose update")
        print(f"view: open {viewer.url} in a browser (Ctrl-C stops)", flush=True)
        threading.Event().wait()
    finally:
        viewer.stop()
    return 0
