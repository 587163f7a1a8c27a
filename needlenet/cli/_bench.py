"""``needlenet bench``: run a benchmark suite and report it."""

from __future__ import annotations

import sys
from pathlib import Path

from ._common import CLIError, check_output, seed


def add_parser(sub) -> None:
    from ..bench import SUITES

    p = sub.add_parser("bench", help="run a benchmark suite",
                       description="Run a benchmark suite on seeded data, with classical and "
                                   "learned features through the same back ends, and report "
                                   "measured figures with the machine they ran on.")
    p.add_argument("suite", help=", ".join(SUITES))
    p.add_argument("--quick", action="store_true",
                   help="a shorter run (each suite within about two minutes)")
    p.add_argument("--json", dest="json_out", help="write the rows as JSON (written as they "
                                                   "finish, so an interrupted run keeps them)")
    p.add_argument("--report", help="write a report directory: report.md, results.json, plots")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--data", metavar="DIR",
                   help="external suite: a directory of labelled in-plane (or axial, or volume) "
                        "recordings to run instead of the shipped in-plane PyMUST set: "
                        "sequence files (.npz, needlenet's format) or PLUS sequences (.mha, "
                        ".mhd) whose NeedleTipToReference transforms are the labels, e.g. your "
                        "own tracked-needle recordings, or the shipped axial set "
                        "needlenet/data/external_axial or volume set "
                        "needlenet/data/external_volume")
    p.add_argument("--model", metavar="F.onnx",
                   help="external suite: the in-plane (axial or volume, for such a set) model for "
                        "the learned features (default: the shipped one)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --json file or report")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..bench import SUITES, BenchInterrupted, check_report_dir, run_suite
    from ..io import RecordingError

    if args.suite not in SUITES:
        raise CLIError(f"bench: unknown suite {args.suite!r}; available: {', '.join(SUITES)}")
    out = check_output(args.json_out, ".json", args.overwrite, "--json")
    if args.report is not None:
        try:
            check_report_dir(args.report, args.overwrite)
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    if args.suite != "external" and (args.data is not None or args.model is not None):
        raise CLIError(f"bench {args.suite}: --data and --model belong to the external suite")
    if args.data is not None and not Path(args.data).is_dir():
        raise CLIError(f"bench external: --data {args.data}: not a directory")
    if args.model is not None:
        from ..features import learned_features

        modality = "inplane"
        if args.data is not None:
            from ..bench._external import labelled_files
            from ..io import load_recording

            first = labelled_files(args.data)[:1]
            if first:
                try:
                    modality = load_recording(first[0]).modality  # inplane, axial or volume
                except RecordingError as exc:
                    raise CLIError(f"bench external: {exc}") from None
        try:  # the checks every model passes before it tracks anything
            learned_features(modality, args.model)
        except ValueError as exc:  # ModelError included
            raise CLIError(f"bench external: --model: {exc}") from None
    try:
        result = run_suite(args.suite, quick=args.quick, json_out=out, seed=args.seed,
                           report_dir=args.report, overwrite=args.overwrite, data=args.data,
                           model=args.model)
    except FileNotFoundError as exc:
        raise CLIError(f"bench {args.suite}: {exc}") from None
    except RecordingError as exc:  # a recording of --data that cannot be read or measured
        raise CLIError(f"bench {args.suite}: {exc}") from None
    except BenchInterrupted as exc:
        print(f"needlenet: {exc}", file=sys.stderr)
        return 130
    print()
    print(result["markdown"])
    for p in (out, result.get("report")):
        if p:
            print(f"wrote {p}")
    return 0
