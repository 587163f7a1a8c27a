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


# -- synth --------------------------------------------------------------------------------

def _add_synth(sub) -> None:
    p = sub.add_parser(
        "synth", help="simulate a labelled needle-insertion sequence",
        description="Simulate a labelled ultrasound sequence of a needle insertion "
                    "(Field-II-style convolution model) and write it as a .npz sequence file "
                    "or a PLUS sequence metafile (.seq.mha) for 3D Slicer.")
    p.add_argument("scenario", nargs="?", help="inplane, volume, volume-motion, axial or servo")
    p.add_argument("--out", help="output sequence file (.npz, or .mha/.mhd for PLUS)")
    p.add_argument("--format", choices=["npz", "plus"],
                   help="npz (the sequence file) or plus (a PLUS sequence metafile with "
                        "ProbeToReference and NeedleTipToReference transforms); default: by "
                        "the --out suffix")
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

    from .trackers._registry import parse_value

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
        raise CLIError("synth: --out FILE.npz (or FILE.seq.mha) is required")
    fmt, out = _synth_output(args)
    preview = _check_output(args.preview, ".png", args.overwrite, "preview")
    overrides = {}
    for item in args.param:
        if "=" not in item:
            raise CLIError(f"synth: --param {item!r}: expected NAME=VALUE")
        k, v = item.split("=", 1)
        overrides[k.strip()] = parse_value(v)
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
    if fmt == "plus":
        from .io import RecordingError, save_plus_sequence

        try:
            save_plus_sequence(seq, out, overwrite=args.overwrite)
        except RecordingError as exc:
            raise CLIError(f"synth: {exc}") from None
    else:
        synth.save_sequence(seq, out, overwrite=args.overwrite)
    print(f"wrote {out}: {seq.n_frames} {seq.modality} frames of {seq.images.shape[1:]} "
          f"at {tuple(round(float(s), 4) for s in seq.spacing_mm)} mm")
    if preview is not None:
        synth.save_preview(seq, preview, overwrite=args.overwrite)
        print(f"wrote {preview}")
    return 0


def _synth_output(args) -> tuple[str, Path]:
    """The output format (by ``--format`` or the suffix) and the checked output path."""
    suffix = Path(args.out).suffix.lower()
    fmt = args.format or ("plus" if suffix in (".mha", ".mhd") else "npz")
    if fmt == "plus":
        return fmt, _check_plus_output(args.out, args.overwrite, "output")
    return fmt, _check_output(args.out, ".npz", args.overwrite, "output")


def _check_plus_output(path: str, overwrite: bool, what: str) -> Path:
    """A PLUS output (``.mha``, ``.seq.mha``, or ``.mhd`` with its ``.zraw``): checked like
    every output, the data file next to an ``.mhd`` included."""
    from .io._metaimage import plus_outputs

    suffix = Path(path).suffix.lower()
    if suffix not in (".mha", ".mhd"):
        raise CLIError(f"{what} {path}: a PLUS sequence file must end in .mha or .mhd "
                       "(e.g. NAME.seq.mha)")
    first = _check_output(path, suffix, overwrite, what)
    for extra in plus_outputs(first)[1:]:
        if extra.exists() and not overwrite:
            raise CLIError(f"{what} {extra} exists; pass --overwrite to replace it")
    return first


# -- track --------------------------------------------------------------------------------

def _add_track(sub) -> None:
    p = sub.add_parser("track", help="track the needle in a sequence file or a recording",
                       description="Run a tracker on a sequence file or a recording of your own "
                                   "(PLUS .mha/.mhd, NRRD, a folder of image frames, a video); "
                                   "with labels, report the paper's metrics. Results can be "
                                   "written as a PLUS sequence for 3D Slicer and streamed live "
                                   "over OpenIGTLink.")
    p.add_argument("file", help="sequence file (.npz), PLUS sequence (.mha/.mhd), NRRD (.nrrd), "
                                "a folder of PNG frames or a video (.mp4, .avi, ...)")
    p.add_argument("--tracker", choices=["inplane", "volume", "axial"],
                   help="default: the file's modality (2D frames without one: inplane)")
    p.add_argument("--method",
                   help="inplane: line (default: the needle found anywhere in the frame), df om "
                        "om+f kf kf+f pf pf+f kfv kfv+f pfv pfv+f (Mathiassen 2017); volume: "
                        "roi-rk (default) ransac chatelain; axial: carriere")
    p.add_argument("--features", choices=["classical", "learned"],
                   help="default: learned (the shipped model)")
    p.add_argument("--angle", type=float, metavar="DEG",
                   help="inplane: the insertion angle to the skin when known (0-90); the "
                        "search then keeps near it")
    p.add_argument("--model", help="an ONNX model instead of the shipped one")
    p.add_argument("--json", dest="json_out", help="write per-frame results and the summary")
    p.add_argument("--overlay", help="write an overlay animation (.gif, .mp4 or .avi)")
    p.add_argument("--spacing", metavar="MM|DZ,DX",
                   help="pixel spacing in mm, one value or per array axis (depth first); "
                        "overrides the file's and is required when it has none")
    p.add_argument("--crop", metavar="X,Y,W,H",
                   help="keep only this pixel rectangle of 2D frames (the image area of a "
                        "screen capture)")
    p.add_argument("--fps", type=float,
                   help="frame rate, for recordings without frame times (overrides them)")
    p.add_argument("--out-plus", metavar="FILE.seq.mha",
                   help="write the images and a NeedleTipToReference transform per frame as a "
                        "PLUS sequence (.mha or .mhd) for 3D Slicer's Sequences module")
    p.add_argument("--igtl", type=int, metavar="PORT",
                   help="stream each frame over OpenIGTLink on this port: IMAGE, the "
                        "NeedleTipToReference TRANSFORM, tip and entry POINTs")
    p.add_argument("--igtl-host", default="127.0.0.1",
                   help="127.0.0.1 (default, this machine only) or a network interface name")
    p.add_argument("--igtl-wait", type=float, default=0.0, metavar="S",
                   help="wait up to S seconds for an OpenIGTLink client before tracking")
    p.add_argument("--realtime", action="store_true",
                   help="pace the frames at their timestamps (for watching a stream live)")
    p.add_argument("--seed", type=int, default=0, help="seed of randomised methods")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a tracker parameter: a field of InplaneParams, VolumeTrackerParams "
                        "or AxialParams (e.g. intensity_threshold=70, image_refine=false, "
                        "insertion.variance_threshold_mm2=90); repeatable")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_track)


def _load_for_track(args):
    """The recording as a sequence; bad input becomes one CLIError line."""
    import numpy as np

    import synth

    from .io import RecordingError, load_recording
    from .io._recording import parse_crop, parse_spacing

    try:
        spacing = None if args.spacing is None else parse_spacing(args.spacing)
        crop = None if args.crop is None else parse_crop(args.crop)
        is_npz = Path(args.file).suffix.lower() == ".npz"
        modality = None if is_npz or args.tracker == "volume" else args.tracker
        seq = load_recording(args.file, modality=modality, spacing_mm=spacing, crop=crop,
                             fps=args.fps)
    except (RecordingError, synth.SequenceFileError) as exc:
        raise CLIError(str(exc)) from None
    if seq.meta.get("format") == "plus" and args.spacing is None and \
            np.allclose(seq.spacing_mm, 1.0):
        print(f"needlenet: note: {args.file} says ElementSpacing = 1 (PLUS's default, pixels); "
              "pass --spacing if a pixel is not 1 mm", file=sys.stderr)
    return seq


def _open_stream(args):
    if args.igtl is None:
        return None
    from .io import IGTLStreamer, StreamError

    try:
        streamer = IGTLStreamer(args.igtl, host=args.igtl_host)
    except StreamError as exc:
        raise CLIError(f"--igtl: {exc}") from None
    print(f"OpenIGTLink: serving on {streamer.host}:{streamer.port}", file=sys.stderr)
    if args.igtl_wait > 0 and not streamer.wait_for_client(args.igtl_wait):
        print(f"OpenIGTLink: no client after {args.igtl_wait:g} s; tracking anyway (frames are "
              "sent once a client connects)", file=sys.stderr)
    return streamer


def _check_method(args) -> None:
    """Fill in the default method and features of ``args.tracker`` and check the method."""
    from .trackers._registry import DEFAULT_FEATURES, DEFAULT_METHODS, tracker_methods

    args.method = args.method or DEFAULT_METHODS[args.tracker]
    args.features = args.features or DEFAULT_FEATURES
    if args.method not in tracker_methods(args.tracker):
        raise CLIError(f"track: tracker {args.tracker!r} has no method {args.method!r}; "
                       f"choose one of {', '.join(tracker_methods(args.tracker))}")


def _track_params(args):
    """``--param`` settings as the tracker's parameter class (None without any)."""
    from .trackers._registry import tracker_params

    if not args.param:
        return None
    try:
        return tracker_params(args.tracker, args.param, args.method)
    except (ValueError, TypeError) as exc:
        raise CLIError(f"track: --param: {exc}") from None


def _cmd_track(args) -> int:
    import json
    import time

    import numpy as np

    from .eval import evaluate, latency_summary
    from .trackers._base import frames_from_sequence
    from .trackers._registry import make_tracker

    out_json = _check_output(args.json_out, ".json", args.overwrite, "--json")
    overlay = None
    if args.overlay:
        suffix = Path(args.overlay).suffix.lower()
        if suffix not in (".gif", ".mp4", ".avi"):
            raise CLIError(f"--overlay {args.overlay}: use .gif, .mp4 or .avi")
        overlay = _check_output(args.overlay, suffix, args.overwrite, "--overlay")
    out_plus = None if args.out_plus is None else \
        _check_plus_output(args.out_plus, args.overwrite, "--out-plus")
    if args.igtl is not None and not 0 <= args.igtl <= 65535:
        raise CLIError(f"--igtl {args.igtl}: a port is 0 to 65535")
    if args.angle is not None and args.tracker not in (None, "inplane"):
        raise CLIError(f"track: --angle is for the inplane tracker, not {args.tracker!r}")
    if args.angle is not None and not 0.0 <= args.angle <= 90.0:
        raise CLIError(f"track: --angle {args.angle:g}: an insertion angle is 0 to 90 degrees")
    if args.tracker is not None:
        _check_method(args)
        params = _track_params(args)  # checked before the recording is read
    seq = _load_for_track(args)
    if args.tracker is None:
        args.tracker = seq.modality
        _check_method(args)
        params = _track_params(args)
    if seq.modality != args.tracker:
        raise CLIError(f"track: {args.file} holds {seq.modality!r} frames "
                       f"({seq.ndim}D); the {args.tracker!r} tracker needs "
                       f"{'3D volumes' if args.tracker == 'volume' else args.tracker + ' images'}")
    kw = {"seed": args.seed}
    if params is not None:
        kw["params"] = params
    if args.angle is not None:
        kw["expected_angle_deg"] = args.angle
    try:
        tracker = make_tracker(args.tracker, args.method, args.features, args.model, **kw)
    except (ValueError, FileNotFoundError) as exc:
        raise CLIError(f"track: {exc}") from None
    from synth._render import Progress

    streamer = _open_stream(args)
    bar = Progress(seq.n_frames, f"track {args.tracker}/{args.method}", not args.quiet)
    estimates = []
    ts = np.asarray(seq.timestamps_s, float)
    start = time.perf_counter()
    try:
        for i, frame in enumerate(frames_from_sequence(seq)):
            if args.realtime:
                time.sleep(max(0.0, (ts[i] - ts[0]) - (time.perf_counter() - start)))
            est = tracker.update(frame)
            estimates.append(est)
            bar.update()
            if streamer is not None:
                entry = est.extras.get("entry_mm", est.extras.get("axis_point_mm"))
                streamer.send_frame(seq.images[i], seq.spacing_mm, est.tip_mm, est.direction,
                                    entry, est.status, origin=seq.origin_mm,
                                    probe_pose=None if seq.probe_pose is None
                                    else seq.probe_pose[i], timestamp=None)
    finally:
        if streamer is not None:
            streamer.close()
            print(f"OpenIGTLink: sent {streamer.frames_sent} frames, skipped "
                  f"{streamer.frames_skipped} (no client)", file=sys.stderr)
    summary = {"file": str(args.file), "tracker": args.tracker, "method": args.method,
               "features": args.features, "frames": seq.n_frames}
    if seq.has_labels:
        summary.update(evaluate(args.tracker, estimates, seq)["summary"])
    else:
        summary.update(latency_summary(estimates))
    statuses = [e.status.value for e in estimates]
    summary["status_counts"] = {s: statuses.count(s) for s in sorted(set(statuses))}
    print(json.dumps({k: v for k, v in summary.items() if not isinstance(v, dict)}, indent=1))
    if out_json is not None:
        out_json.write_text(json.dumps({"frames": [e.to_json() for e in estimates],
                                        "summary": summary}, indent=1, default=float))
        print(f"wrote {out_json}")
    if overlay is not None:
        from .io import write_overlay

        write_overlay(overlay, seq, estimates)
        print(f"wrote {overlay}")
    if out_plus is not None:
        from .io import RecordingError, save_plus_sequence

        try:
            save_plus_sequence(seq, out_plus, estimates, overwrite=args.overwrite)
        except RecordingError as exc:
            raise CLIError(f"--out-plus: {exc}") from None
        print(f"wrote {out_plus}")
    return 0


# -- train / export -----------------------------------------------------------------------

_TRAIN_EXTRA = ("needs the training extra (torch, lightning, onnx): "
                "pip install torch==2.13.0 && pip install 'needlenet[train]'")


def _require_training(cmd: str) -> None:
    import importlib.util

    def absent(name: str) -> bool:
        try:
            return importlib.util.find_spec(name) is None
        except (ImportError, ValueError):
            return True

    missing = [m for m in ("torch", "lightning", "onnx") if absent(m)]
    if missing:
        raise CLIError(f"{cmd} {_TRAIN_EXTRA} (missing: {', '.join(missing)})")


def _add_train(sub) -> None:
    p = sub.add_parser("train", help="train a needle likelihood network on synth data",
                       description="Train a likelihood network (shaft and tip maps) on "
                                   "sequences simulated on the fly. " + _TRAIN_EXTRA)
    p.add_argument("model", help="inplane, axial or volume")
    p.add_argument("--steps", type=int, help="optimisation steps (default: the shipped recipe)")
    p.add_argument("--out", help="output directory (default runs/MODEL)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2,
                   help="data-generating processes (default 2: the trainer itself needs little)")
    p.add_argument("--accelerator", default="cpu", choices=("cpu", "gpu", "auto"),
                   help="where the network trains (default cpu, as the shipped models did; "
                        "on a GPU machine the simulation is the bottleneck: raise --workers)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="change one setting of the recipe: a field of training.train."
                        "TrainConfig or of its DataConfig, e.g. --param width=16 --param "
                        "crop=48 --param cr_range=1.5,3.0; repeatable")
    p.add_argument("--export", help="also export the result to this .onnx file")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=_cmd_train)


def _cmd_train(args) -> int:
    if args.model not in ("inplane", "axial", "volume"):
        raise CLIError(f"train: unknown model {args.model!r}; choose inplane, axial or volume")
    if args.steps is not None and args.steps < 1:
        raise CLIError(f"train: --steps must be positive, got {args.steps}")
    export = _check_output(args.export, ".onnx", args.overwrite, "--export")
    _require_training("train")
    from training.train import config_for, settings_for, train

    changes = {"seed": args.seed, "num_workers": args.workers,
               "accelerator": args.accelerator}
    if args.steps is not None:
        changes["steps"] = args.steps
    if args.out:
        changes["out_dir"] = args.out
    try:
        settings = settings_for(args.model, args.param)
        own = sorted(set(settings) & {"seed", "num_workers", "accelerator", "steps", "out_dir"})
        if own:
            raise ValueError(f"set {', '.join(own)} with its own option (--seed, --workers, "
                             "--accelerator, --steps, --out), not --param")
        cfg = config_for(args.model, **changes, **settings)
    except ValueError as exc:
        raise CLIError(f"train: --param: {exc}") from None
    if cfg.accelerator == "gpu":
        import torch

        if not torch.cuda.is_available():
            raise CLIError(f"train: --accelerator gpu, but torch {torch.__version__} sees no "
                           "GPU")
    out = Path(cfg.out_dir)
    if (out / "model.ckpt").exists() and not args.overwrite:
        raise CLIError(f"train: {out / 'model.ckpt'} exists; pass --overwrite or --out DIR")
    metrics = train(cfg)
    for k, v in metrics.items():
        print(f"{k}: {v}")
    if export is not None:
        from training.export import export_onnx, load_checkpoint

        net, hp = load_checkpoint(metrics["checkpoint"])
        r = export_onnx(net, hp["modality"], hp["spacing_mm"], export, overwrite=args.overwrite,
                        extra_metadata={"train_steps": cfg.steps, "train_seed": args.seed,
                                        **({"train_params": " ".join(args.param)}
                                           if args.param else {})},
                        target_reference=hp.get("target_reference", "centerline"),
                        normalization=hp.get("normalization", "fixed"))
        print(f"wrote {export} ({r['bytes']} bytes, onnxruntime vs torch {r['max_abs_diff']:.1e})")
    return 0


def _add_export(sub) -> None:
    p = sub.add_parser("export", help="export a training checkpoint to ONNX",
                       description="Export a checkpoint to ONNX (input 'image', output "
                                   "'likelihood', dynamic spatial axes), verified against torch.")
    p.add_argument("checkpoint")
    p.add_argument("--out", required=True, help="the .onnx file")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=_cmd_export)


def _cmd_export(args) -> int:
    out = _check_output(args.out, ".onnx", args.overwrite, "--out")
    _require_training("export")
    from training.export import ExportError, export_onnx, load_checkpoint

    try:
        net, hp = load_checkpoint(args.checkpoint)
        r = export_onnx(net, hp["modality"], hp["spacing_mm"], out, overwrite=args.overwrite,
                        target_reference=hp.get("target_reference", "centerline"),
                        normalization=hp.get("normalization", "fixed"))
    except (ValueError, ExportError) as exc:
        raise CLIError(f"export: {exc}") from None
    print(f"wrote {out} ({r['bytes']} bytes, opset {r['opset']}, IR {r['ir_version']}, "
          f"onnxruntime vs torch {r['max_abs_diff']:.1e})")
    return 0


# -- servo --------------------------------------------------------------------------------

def _add_servo(sub) -> None:
    from .servo._cli import add_servo_parser

    add_servo_parser(sub)


# -- bench --------------------------------------------------------------------------------

def _add_bench(sub) -> None:
    from .bench import SUITES

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
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --json file or report")
    p.set_defaults(func=_cmd_bench)


def _cmd_bench(args) -> int:
    from .bench import SUITES, BenchInterrupted, check_report_dir, run_suite

    if args.suite not in SUITES:
        raise CLIError(f"bench: unknown suite {args.suite!r}; available: {', '.join(SUITES)}")
    out = _check_output(args.json_out, ".json", args.overwrite, "--json")
    if args.report is not None:
        try:
            check_report_dir(args.report, args.overwrite)
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    try:
        result = run_suite(args.suite, quick=args.quick, json_out=out, seed=args.seed,
                           report_dir=args.report, overwrite=args.overwrite)
    except BenchInterrupted as exc:
        print(f"needlenet: {exc}", file=sys.stderr)
        return 130
    print()
    print(result["markdown"])
    for p in (out, result.get("report")):
        if p:
            print(f"wrote {p}")
    return 0


# -- demo ---------------------------------------------------------------------------------

def _add_demo(sub) -> None:
    p = sub.add_parser("demo", help="the main job: simulate, track with classical and learned "
                                    "features, servo, and write a report",
                       description="Make a few seeded sequences of each modality, track them "
                                   "with classical and with learned features (the shipped "
                                   "ONNX models; no training needed), run a short servo loop, "
                                   "and write a report with the comparison table, plots and "
                                   "an overlay animation.")
    p.add_argument("--out", default="needlenet-demo",
                   help="report directory (default: needlenet-demo)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    p.add_argument("--quiet", action="store_true", help="less progress output")
    p.set_defaults(func=_cmd_demo)


def _cmd_demo(args) -> int:
    from .bench import check_report_dir
    from .demo import run_demo

    try:
        out = check_report_dir(args.out, args.overwrite)
    except ValueError as exc:
        raise CLIError(str(exc).replace("--report", "--out")) from None
    report = run_demo(out, seed=args.seed, quiet=args.quiet)
    print(f"report: {report}")
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
    _add_track(sub)
    _add_train(sub)
    _add_export(sub)
    _add_servo(sub)
    _add_bench(sub)
    _add_demo(sub)
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
