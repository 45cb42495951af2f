"""Options shared by several commands: profile selection and ``--set`` overrides."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_profile_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="phone",
                   help="profile name (see profiles/: phone, desktop, board, ...) or a TOML file (default: phone)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a profile value, e.g. --set tracking.huber=2.0 (repeatable)")


def config_from_args(args, extra=()):
    from ..config import load_profile
    return load_profile(args.profile, list(args.overrides) + list(extra))


def add_viewer_args(p) -> None:
    """``--viewer``, ``--rrd FILE``, ``--connect HOST:PORT`` (rerun; the ``[viewer]`` extra)."""
    g = p.add_argument_group("viewer (rerun; pip install 'lite-vo[viewer]')")
    g.add_argument("--viewer", action="store_true", help="open a live rerun viewer on this machine")
    g.add_argument("--rrd", type=Path, default=None, help="record the run for the rerun viewer (FILE.rrd)")
    g.add_argument("--connect", default=None, metavar="HOST:PORT",
                   help="stream the run to a rerun viewer elsewhere (run `rerun` there; default port 9876)")


def viewer_sinks(args) -> list:
    """The viewer sink the options ask for (none when they are off: zero cost)."""
    from ..viewer import RerunSink, parse_target
    target = parse_target(args.viewer, args.rrd, args.connect)
    if target is None:
        return []
    if target[0] == "rrd":
        from ..io import check_output_file
        check_output_file(args.rrd, getattr(args, "force", False))
    return [RerunSink(*target)]
