"""Options shared by several commands: profile selection and ``--set`` overrides."""
from __future__ import annotations

import argparse


def add_profile_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="phone",
                   help="profile name (see profiles/: phone, desktop, board, ...) or a TOML file (default: phone)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a profile value, e.g. --set tracking.huber=2.0 (repeatable)")


def config_from_args(args, extra=()):
    from ..config import load_profile
    return load_profile(args.profile, list(args.overrides) + list(extra))
