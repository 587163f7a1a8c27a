"""``needlenet demo``: the main job, simulate, track, servo and write a report."""

from __future__ import annotations

from ._common import CLIError, seed


def add_parser(sub) -> None:
    p = sub.add_parser("demo", help="the main job: simulate, track with classical and learned "
                                    "features, servo, and write a report",
                       description="Make a few seeded sequences of each modality, track them "
                                   "with classical and with learned features (the shipped "
                                   "ONNX models; no training needed), run a short servo loop, "
                                   "and write a report with the comparison table, plots and "
                                   "an overlay animation.")
    p.add_argument("--out", default="needlenet-demo",
                   help="report directory (default: needlenet-demo)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    p.add_argument("--quiet", action="store_true", help="less progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..bench import check_report_dir
    from ..demo import run_demo

    try:
        out = check_report_dir(args.out, args.overwrite)
    except ValueError as exc:
        raise CLIError(str(exc).replace("--report", "--out")) from None
    report = run_demo(out, seed=args.seed, quiet=args.quiet)
    print(f"report: {report}")
    return 0
