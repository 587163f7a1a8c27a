"""``needlenet servo``: the probe-servo loops (Ye 2025, Chatelain 2013) from the command line,
and their rows as a table."""

from __future__ import annotations

import json
import sys

from ._common import CLIError, check_output, seed

# exit status of a run that a safety stop ended, by its cause (0: no stop, 2: a user error)
STOP_EXIT_CODES = {"needle_lost": 3, "never_found": 4, "stale_feed": 5, "stuck_detector": 6,
                   "unconfirmed_travel": 7}
FAULT_NAMES = ("frozen-feed", "stuck-detector", "needle-lost", "never-found")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "servo", help="run the probe-servo loop (Ye 2025, Chatelain 2013)",
        description="Closed probe-servo loops. 'servo': Ye 2025's EKF + PI/PD tracking of a 2D "
                    "transverse probe (features ideal: section 4.1's noisy measurement, Table "
                    "2; learned/classical: each frame imaged from the probe's pose). "
                    "'volume-motion': Chatelain 2013's 3-DOF visual servoing of a 3D probe "
                    "(runs misalignment and motion). Every safety stop is printed; the exit "
                    "status names the first one's cause: " + ", ".join(
                        f"{c} {k}" for k, c in STOP_EXIT_CODES.items()) + " (0: no stop).")
    p.add_argument("scenario", help="servo | volume-motion")
    p.add_argument("--filter", action="append", metavar="pv|prv|all",
                   help="EKF state (repeatable or comma-separated; default all)")
    p.add_argument("--gain", action="append", metavar="dynamic|constant|all",
                   help="K_e law (repeatable or comma-separated; default all)")
    p.add_argument("--features", action="append", metavar="learned|classical|ideal|all",
                   help="measurement (default: ideal for servo, classical,learned for "
                        "volume-motion)")
    p.add_argument("--run", action="append", metavar="misalignment|motion|all",
                   help="volume-motion runs (default all)")
    p.add_argument("--repeat", type=int, default=None,
                   help="repetitions (seeds seed..seed+N-1; default 100 ideal, 3 images, "
                        "1 volume-motion)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--model", default=None, help="ONNX model instead of the shipped one")
    p.add_argument("--quick", action="store_true", help="short runs (under about a minute)")
    p.add_argument("--fault", choices=FAULT_NAMES,
                   help="inject a fault half way through every run (the insertion's half for "
                        "volume-motion) to exercise the safety stops")
    p.add_argument("--json", default=None, help="write the rows to this .json")
    p.add_argument("--plot", default=None, help="write trajectories to this .png")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def _values(given, allowed: tuple[str, ...], default: tuple[str, ...], what: str):
    if not given:
        return default
    out: list[str] = []
    for item in given:
        for v in str(item).split(","):
            v = v.strip().lower()
            if v == "all":
                out.extend(allowed)
            elif v not in allowed:
                raise CLIError(f"unknown {what} {v!r}; choose one of {', '.join(allowed)} "
                               "or all")
            else:
                out.append(v)
    return tuple(dict.fromkeys(out))


def run(args) -> int:
    from ..servo import _api

    if args.scenario not in _api.SCENARIOS:
        raise CLIError(f"unknown scenario {args.scenario!r}; choose one of "
                       f"{', '.join(_api.SCENARIOS)}")
    servo = args.scenario == "servo"
    filters = _values(args.filter, _api.FILTERS, _api.FILTERS, "filter")
    gains = _values(args.gain, _api.GAINS, _api.GAINS, "gain")
    feats = _values(args.features, _api.FEATURES_2D if servo else _api.FEATURES_3D,
                    ("ideal",) if servo else _api.FEATURES_3D, "features")
    runs = _values(args.run, _api.RUNS_3D, _api.RUNS_3D, "run")
    if args.repeat is not None and args.repeat < 1:
        raise CLIError(f"--repeat must be a positive integer, got {args.repeat}")
    if args.seed < 0:
        raise CLIError(f"--seed must be non-negative, got {args.seed}")
    json_path = check_output(args.json, ".json", args.overwrite, "--json")
    plot_path = check_output(args.plot, ".png", args.overwrite, "--plot")
    try:
        _api.check_options(args.scenario, filters, gains, feats, args.repeat, args.model,
                           args.seed)
    except ValueError as exc:  # ModelError included
        raise CLIError(str(exc).splitlines()[0]) from None

    def progress(done, total, label):
        if not args.quiet:
            sys.stderr.write(f"\rservo {done}/{total} {label:<40}")
            if done == total:
                sys.stderr.write("\n")
            sys.stderr.flush()

    traces: list = []
    rows = _api.servo_rows(args.scenario, filters=filters, gains=gains, features=feats,
                           runs=runs, repeats=args.repeat, seed=args.seed, model=args.model,
                           quick=args.quick, progress=progress, traces=traces,
                           fault=args.fault)
    if not args.quiet:
        print(format_table(rows))
    stops = [(r, stop) for r in rows for stop in r.get("stops", [])]
    for r, stop in stops:
        print(f"needlenet: safety stop: {stop['reason']} ({_config(r)}, seed {stop['seed']}) "
              f"at {stop['time_s']:.2f} s" + (
                  f", {stop['since_fault_s']:.2f} s and {stop['travel_since_fault_mm']:.2f} mm "
                  f"of probe travel after the {stop['fault']} fault" if "fault" in stop else ""),
              file=sys.stderr)
    if json_path is not None:
        from ..bench import machine_description

        doc = {"scenario": args.scenario, "rows": rows, "machine": machine_description(),
               "quick": bool(args.quick), "events": [t.events for t in traces],
               "note": "latencies: wall time per cycle (time.perf_counter), with and without "
                       "the simulated scanner's imaging; other jobs may share the CPU"}
        from ..io import atomic_write

        text = json.dumps(doc, indent=1, default=_json_default)
        atomic_write({json_path: lambda fh: fh.write(text.encode())}, overwrite=True)
    if plot_path is not None:
        from ..servo import plot_runs

        plot_runs(traces, plot_path, f"needlenet servo {args.scenario}")
    return STOP_EXIT_CODES[stops[0][1]["reason"]] if stops else 0


def _config(row: dict) -> str:
    if row["scenario"] == "servo":
        return f"{row['features']} {row['gain']}-{row['filter']}"
    return f"{row['features']} {row['run']}"


def _json_default(o):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def format_table(rows: list[dict]) -> str:
    """Ye's Table 2 (ours beside the paper's) or Chatelain's errors at rest, as text."""
    if not rows:
        return "(no rows)"
    lines = []
    if rows[0]["scenario"] == "servo":
        lines.append(f"{'features':<9} {'gain-filter':<16} {'RMSE P':>15} {'RMSE v_x':>15} "
                     f"{'RMSE p_ux':>15} {'RMSE p_uy':>15} {'lead/lag':>13} {'in-plane':>8} "
                     f"{'lat ms p50/p99':>15} {'+img p50/p99':>14}")
        lines.append(f"{'':<26}{'(ours / Ye)':>15}")
        for r in rows:
            def pair(a, b, fmt="{:.4f}"):
                return f"{fmt.format(a)}/{fmt.format(b)}"
            lines.append(
                f"{r['features']:<9} {r['gain'] + '-' + r['filter']:<16} "
                f"{pair(r['rmse_p_mm'], r['paper_rmse_p_mm']):>15} "
                f"{pair(r['rmse_vx_mm_s'], r['paper_rmse_vx_mm_s']):>15} "
                f"{pair(r['rmse_pux_mm'], r['paper_rmse_pux_mm']):>15} "
                f"{pair(r['rmse_puy_mm'], r['paper_rmse_puy_mm']):>15} "
                f"{pair(r['lead_lag_ratio'], r['paper_lead_lag_ratio'], '{:.3f}'):>13} "
                f"{r['in_plane_fraction']:>8.3f} "
                f"{r['latency_median_ms']:>6.2f}/{r['latency_p99_ms']:<7.2f} "
                f"{r['latency_with_imaging_median_ms']:>6.2f}/"
                f"{r['latency_with_imaging_p99_ms']:<7.2f}")
        lines.append("units: mm, mm/s; lead/lag = frames ahead / frames behind; in-plane = "
                     "probe behind the tip with the crossing in the image")
        return "\n".join(lines)
    lines.append(f"{'features':<10} {'run':<13} {'rest |e_X| mm':>14} {'|e_Z| mm':>10} "
                 f"{'|e_Th| deg':>10} {'true X/Z/Th':>18} {'RMSE tip':>9} {'in vol':>7} "
                 f"{'tracked':>7} {'lat ms p50/p99':>15} {'+img p50/p99':>15}")
    for r in rows:
        lines.append(
            f"{r['features']:<10} {r['run']:<13} {r['rest_err_x_mm']:>14.2f} "
            f"{r['rest_err_z_mm']:>10.2f} {r['rest_err_theta_deg']:>10.2f} "
            f"{r['rest_true_err_x_mm']:>6.2f}/{r['rest_true_err_z_mm']:.2f}/"
            f"{r['rest_true_err_theta_deg']:<6.2f} {r['rmse_p_mm']:>9.2f} "
            f"{r['in_plane_fraction']:>7.2f} {r['tracked_fraction']:>7.2f} "
            f"{r['latency_median_ms']:>6.1f}/{r['latency_p99_ms']:<7.1f} "
            f"{r['latency_with_imaging_median_ms']:>6.0f}/{r['latency_with_imaging_p99_ms']:<7.0f}")
    lines.append(f"{'Chatelain 2013 (misalignment, at rest)':<24} {1.10:>3.2f} mm  {0.23:.2f} mm "
                 f" {0.97:.2f} deg (estimated features)")
    return "\n".join(lines)
