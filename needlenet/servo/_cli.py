"""``needlenet servo``: the probe-servo loop from the command line (issue 5)."""

from __future__ import annotations


def add_servo_parser(sub) -> None:
    p = sub.add_parser("servo", help="run the probe-servo loop (Ye 2025, Chatelain 2013)")
    p.set_defaults(func=_cmd_servo)


def _cmd_servo(args) -> int:
    from ..cli import CLIError

    raise CLIError("servo: not implemented yet")
