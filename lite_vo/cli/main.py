"""The ``lite-vo`` entry point: one argparse parser with a sub-parser per command.

Each command lives in ``lite_vo/cli/<name>.py`` with ``add_parser(subparsers)`` (argparse only,
no heavy imports) and ``run(args) -> int``. Known errors (:class:`LiteVOError`) become one line
on stderr and exit status 1; anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

from ..errors import LiteVOError

COMMANDS = ("run", "eval", "synth", "profile", "warmup", "ar", "demo", "calibrate")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    parser = argparse.ArgumentParser(
        prog="lite-vo",
        description="Semi-dense direct monocular visual odometry for low-power devices.")
    parser.add_argument("--version", action="version", version=f"lite-vo {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"{__package__}.{name}")
        except ModuleNotFoundError as err:
            if err.name != f"{__package__}.{name}":
                raise
            continue
        p = module.add_parser(sub)
        p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args._module.run(args) or 0)
    except LiteVOError as err:
        print(f"lite-vo {args.command}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"lite-vo {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
