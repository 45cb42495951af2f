"""The ``lite-vo`` entry point: one argparse parser with a sub-parser per command.

Each command is a module with ``add_parser(subparsers)`` (argparse only, no heavy imports) and
``run(args) -> int``: the core's live in ``lite_vo/cli/<name>.py``; plug-ins (the AR demo) add
theirs through the entry-point group ``lite_vo.commands`` (name = command, value = module), so the
core names no plug-in. Known errors (:class:`LiteVOError`) become one line on stderr and exit
status 1; Ctrl-C exits with 130 and SIGTERM with 143 after the command finished its files;
anything else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
from importlib.metadata import entry_points

from ..errors import Interrupted, LiteVOError

COMMANDS = ("run", "eval", "synth", "profile", "warmup", "calibrate")
COMMAND_ENTRY_POINTS = "lite_vo.commands"


def command_modules() -> dict[str, str]:
    """Command name -> module: the core's, then the plug-ins' (which cannot replace a core command)."""
    found = {name: f"{__package__}.{name}" for name in COMMANDS}
    for ep in sorted(entry_points(group=COMMAND_ENTRY_POINTS), key=lambda e: e.name):
        found.setdefault(ep.name, ep.value)
    return found


class _StderrHandler(logging.Handler):
    """Log lines on stderr that do not break a tqdm progress bar."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


def _raise_interrupted(signum, frame):
    raise Interrupted(signum)


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__
    parser = argparse.ArgumentParser(
        prog="lite-vo",
        description="Semi-dense direct monocular visual odometry for low-power devices.")
    parser.add_argument("--version", action="version", version=f"lite-vo {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name in command_modules().items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as err:
            if err.name != module_name:
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
    quiet = bool(getattr(args, "quiet", False))
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s" if args.verbose
                                           else "lite-vo: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    # normal events at INFO are shown; --quiet keeps warnings only; -v adds debug details
    root.setLevel(logging.DEBUG if args.verbose else logging.WARNING if quiet else logging.INFO)
    for noisy in ("numba", "matplotlib", "PIL", "trimesh", "rosbags"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    try:
        return int(args._module.run(args) or 0)
    except LiteVOError as err:
        print(f"lite-vo {args.command}: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"lite-vo {args.command}: interrupted (Ctrl-C); the outputs so far were written", file=sys.stderr)
        return 130
    except Interrupted:
        print(f"lite-vo {args.command}: terminated (SIGTERM); the outputs so far were written", file=sys.stderr)
        return 143
    except BrokenPipeError:
        # the reader of our output went away (``lite-vo run ... | head``): the run itself finished;
        # point stdout at devnull so the interpreter's final flush does not raise again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
