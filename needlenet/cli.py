"""The ``needlenet`` command line: ``needlenet synth | train | export | track | servo | bench |
demo``.

Every subcommand checks its arguments and outputs before doing any work and reports a bad one
as a single line that names it (exit status 2); nothing a user made is overwritten unless
``--overwrite`` is given.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["main", "CLIError"]


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _check_output(path: str | None, suffix: str, overwrite: bool, what: str) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if p.suffix.lower() != suffix:
        raise CLIError(f"{what} {p}: must end in {suffix}")
    if p.exists() and not overwrite:
        raise CLIError(f"{what} {p} exists; pass --overwrite to replace it")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise CLIError(f"{what} {p}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise CLIError(f"{what} {p}: directory {parent} is not writable")
    return p


def _parse_value(text: str):
    low = text.lower()
    if low in ("none", "null"):
        return None
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return text


# -- synth --------------------------------------------------------------------------------

def _add_synth(sub) -> None:
    p = sub.add_parser(
        "synth", help="simulate a labelled needle-insertion sequence",
        description="Simulate a labelled ultrasound sequence of a needle insertion "
                    "(Field-II-style convolution model) and write it as a .npz sequence file.")
    p.add_argument("scenario", nargs="?", help="inplane, volume, volume-motion, axial or servo")
    p.add_argument("--out", help="output sequence file (.npz)")
    p.add_argument("--frames", type=int, help="number of frames (default: the paper's protocol)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--cr", type=float, help="contrast ratio to reach (Zhao 2013 eq. 9)")
    p.add_argument("--background", choices=["homogeneous", "inhomogeneous"])
    p.add_argument("--speed", type=float, help="insertion speed, mm/s")
    p.add_argument("--angle", type=float,
                   help="insertion angle, degrees (inplane: to the skin; volume: Zhao's alpha)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="any scenario parameter (see --list); repeatable")
    p.add_argument("--preview", help="also draw the first and last frames with ground truth (.png)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    p.add_argument("--list", action="store_true", help="list the scenarios and their parameters")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_synth)


def _cmd_synth(args) -> int:
    import synth

    if args.list:
        print(synth.describe())
        return 0
    if not args.scenario:
        raise CLIError("synth: give a scenario (one of "
                       f"{', '.join(synth.SCENARIOS)}) or --list")
    if args.scenario not in synth.SCENARIOS:
        raise CLIError(f"synth: unknown scenario {args.scenario!r}; choose one of "
                       f"{', '.join(synth.SCENARIOS)}")
    if not args.out:
        raise CLIError("synth: --out FILE.npz is required")
    out = _check_output(args.out, ".npz", args.overwrite, "output")
    preview = _check_output(args.preview, ".png", args.overwrite, "preview")
    overrides = {}
    for item in args.param:
        if "=" not in item:
            raise CLIError(f"synth: --param {item!r}: expected NAME=VALUE")
        k, v = item.split("=", 1)
        overrides[k.strip()] = _parse_value(v.strip())
    cls = synth.SCENARIOS[args.scenario]
    names = {f for f in cls.__dataclass_fields__}
    if args.speed is not None:
        if "speed_mm_s" not in names:
            raise CLIError(f"synth: --speed does not apply to scenario {args.scenario!r}")
        overrides["speed_mm_s"] = args.speed
    if args.angle is not None:
        key = "angle_deg" if "angle_deg" in names else "alpha_deg" if "alpha_deg" in names \
            else None
        if key is None:
            raise CLIError(f"synth: --angle does not apply to scenario {args.scenario!r}")
        overrides[key] = args.angle
    for name in ("frames", "cr", "background"):
        v = getattr(args, name)
        if v is not None:
            overrides[name] = v
    try:
        synth.scenario_params(args.scenario, **overrides)  # validate before any work
    except (ValueError, TypeError) as exc:
        raise CLIError(f"synth: {exc}") from None
    seq = synth.generate(args.scenario, seed=args.seed, progress=not args.quiet, **overrides)
    synth.save_sequence(seq, out, overwrite=args.overwrite)
    print(f"wrote {out}: {seq.n_frames} {seq.modality} frames of {seq.images.shape[1:]} "
          f"at {tuple(round(float(s), 4) for s in seq.spacing_mm)} mm")
    if preview is not None:
        synth.save_preview(seq, preview, overwrite=args.overwrite)
        print(f"wrote {preview}")
    return 0


# -- bench --------------------------------------------------------------------------------

def _add_bench(sub) -> None:
    p = sub.add_parser("bench", help="run a benchmark suite",
                       description="Run a benchmark suite on seeded data and report measured "
                                   "figures with the machine they ran on.")
    p.add_argument("suite", help="synth")
    p.add_argument("--quick", action="store_true", help="a shorter run")
    p.add_argument("--json", dest="json_out", help="write the results as JSON")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    p.set_defaults(func=_cmd_bench)


def _cmd_bench(args) -> int:
    from .bench import SUITES, run_suite

    if args.suite not in SUITES:
        raise CLIError(f"bench: unknown suite {args.suite!r}; available: {', '.join(SUITES)}")
    out = _check_output(args.json_out, ".json", args.overwrite, "--json")
    result = run_suite(args.suite, quick=args.quick, json_out=out, seed=args.seed)
    print()
    print(result["markdown"])
    return 0


# -- entry point --------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="needlenet",
        description="Real-time needle tracking in 2D, axial and 3D ultrasound.")
    from . import __version__

    parser.add_argument("--version", action="version", version=f"needlenet {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_synth(sub)
    _add_bench(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except CLIError as exc:
        print(f"needlenet: error: {exc}", file=sys.stderr)
        return 2
    except (FileExistsError, FileNotFoundError, PermissionError) as exc:
        print(f"needlenet: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("needlenet: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
