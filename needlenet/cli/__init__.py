"""The ``needlenet`` command line: ``needlenet synth | train | export | track | servo | bench |
demo``.

Every subcommand checks its arguments and outputs before doing any work and reports a bad one
as a single line that names it (exit status 2); nothing a user made is overwritten unless
``--overwrite`` is given.

One module per subcommand (``_synth``, ``_track``, ``_train`` with export, ``_servo``,
``_bench``, ``_demo``), each with ``add_parser`` and the function it runs; ``_common`` holds
:class:`CLIError` and the checks of output paths. Nothing outside this package imports it.
"""

from __future__ import annotations

import argparse
import sys

from . import _bench, _demo, _servo, _synth, _track, _train
from ._common import CLIError

__all__ = ["main", "build_parser", "CLIError"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="needlenet",
        description="Real-time needle tracking in 2D, axial and 3D ultrasound.")
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"needlenet {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _synth.add_parser(sub)
    _track.add_parser(sub)
    _train.add_train_parser(sub)
    _train.add_export_parser(sub)
    _servo.add_parser(sub)
    _bench.add_parser(sub)
    _demo.add_parser(sub)
    return parser


def one_line(exc: BaseException) -> str:
    """An error message as one line: a message that quotes a damaged header or a numpy array
    may hold line breaks."""
    return " ".join(str(exc).split()) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (CLIError, OSError) as exc:
        # OSError: a file that vanished, a full disk, a name too long, a permission: the
        # environment's error, as one line (its message names the file)
        print(f"needlenet: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("needlenet: interrupted", file=sys.stderr)
        return 130
