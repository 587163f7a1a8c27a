"""``needlenet track``: run a tracker on a sequence file or a recording and report it."""

from __future__ import annotations

import sys
from pathlib import Path

from ._common import CLIError, check_output, check_plus_output, seed


def add_parser(sub) -> None:
    p = sub.add_parser("track", help="track the needle in a sequence file or a recording",
                       description="Run a tracker on a sequence file or a recording of your own "
                                   "(DICOM, PLUS .mha/.mhd, NRRD, a folder of image frames, a "
                                   "video) or a live OpenIGTLink image stream; "
                                   "with labels, report the paper's metrics. Results can be "
                                   "written as a PLUS sequence for 3D Slicer and streamed live "
                                   "over OpenIGTLink.")
    p.add_argument("file", help="sequence file (.npz), DICOM cine loop (.dcm, or a scanner's "
                                "IM_0001), PLUS sequence (.mha/.mhd), NRRD (.nrrd), a folder of "
                                "PNG frames, a video (.mp4, .avi, ...), or a live OpenIGTLink "
                                "image stream igtl://HOST[:PORT][/DEVICE] (a PLUS Server's)")
    p.add_argument("--tracker", choices=["inplane", "volume", "axial"],
                   help="default: the file's modality (2D frames without one: inplane)")
    p.add_argument("--method",
                   help="inplane: line (default: the needle found anywhere in the frame), df om "
                        "om+f kf kf+f pf pf+f kfv kfv+f pfv pfv+f (Mathiassen 2017); volume: "
                        "roi-rk (default) ransac chatelain; axial: carriere")
    p.add_argument("--features", choices=["classical", "learned"],
                   help="default: learned (the shipped model) in-plane and axial, classical "
                        "for volumes: what tracks best on images needlenet did not make")
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
    p.add_argument("--igtl-idle", type=float, default=5.0, metavar="S",
                   help="igtl:// input: the stream has ended when no frame comes for S "
                        "seconds (default 5)")
    p.add_argument("--igtl-connect", type=float, default=30.0, metavar="S",
                   help="igtl:// input: wait up to S seconds for the first frame (default 30)")
    p.add_argument("--realtime", action="store_true",
                   help="pace the frames at their timestamps (for watching a stream live)")
    p.add_argument("--seed", type=seed, default=0, help="seed of randomised methods")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="a tracker parameter: a field of InplaneParams, VolumeTrackerParams "
                        "or AxialParams (e.g. intensity_threshold=70, image_refine=false, "
                        "insertion.variance_threshold_mm2=90); repeatable")
    p.add_argument("--overwrite", action="store_true")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    out_json, overlay, out_plus = _check_outputs(args)
    if str(args.file).startswith("igtl://"):
        from ._track_live import run_live

        return run_live(args, out_json, overlay, out_plus)
    if args.igtl is not None and not 0 <= args.igtl <= 65535:
        raise CLIError(f"--igtl {args.igtl}: a port is 0 to 65535")
    if args.angle is not None and args.tracker not in (None, "inplane"):
        raise CLIError(f"track: --angle is for the inplane tracker, not {args.tracker!r}")
    if args.angle is not None and not 0.0 <= args.angle <= 90.0:
        raise CLIError(f"track: --angle {args.angle:g}: an insertion angle is 0 to 90 degrees")
    if args.tracker is not None:
        _check_method(args)
        params = _track_params(args)  # checked before the recording is read
    seq = _load(args)
    if args.tracker is None:
        args.tracker = seq.modality
        if args.angle is not None and args.tracker != "inplane":
            raise CLIError(f"track: --angle is for the inplane tracker; {args.file} holds "
                           f"{args.tracker!r} frames")
        _check_method(args)
        params = _track_params(args)
    if seq.modality != args.tracker:
        raise CLIError(f"track: {args.file} holds {seq.modality!r} frames "
                       f"({seq.ndim}D); the {args.tracker!r} tracker needs "
                       f"{'3D volumes' if args.tracker == 'volume' else args.tracker + ' images'}")
    tracker = _make_tracker(args, params)
    _check_model_grid(tracker, seq)
    from ..io import RecordingError

    try:  # a long recording's frames are read as they are tracked: a damaged one is found here
        estimates = _run_tracker(args, tracker, seq)
        _report(args, seq, estimates, out_json, overlay, out_plus, _model_grid(tracker))
    except RecordingError as exc:
        raise CLIError(str(exc)) from None
    return 0


def _check_outputs(args):
    """The checked ``--json``, ``--overlay`` and ``--out-plus`` paths (None where not given);
    none of them may be the recording read (or the data file next to its header)."""
    inputs = _input_files(args.file)
    out_json = check_output(args.json_out, ".json", args.overwrite, "--json", inputs)
    overlay = None
    if args.overlay is not None:
        suffix = Path(args.overlay).suffix.lower()
        if suffix not in (".gif", ".mp4", ".avi"):
            shown = args.overlay if args.overlay.strip() else repr(args.overlay)
            raise CLIError(f"--overlay {shown}: use .gif, .mp4 or .avi")
        overlay = check_output(args.overlay, suffix, args.overwrite, "--overlay", inputs)
    out_plus = None if args.out_plus is None else \
        check_plus_output(args.out_plus, args.overwrite, "--out-plus", inputs)
    return out_json, overlay, out_plus


def _input_files(path: str) -> tuple[Path, ...]:
    """The recording and the files it reads beside it: an .mhd's or .nhdr's data file (the
    one its header names, and those named like it), the sidecar JSON of a video or a folder
    of frames, and the frames of a folder."""
    from ..io import VIDEO_SUFFIXES, sidecar_path

    p = Path(path)
    out = [p]
    suffix = p.suffix.lower()
    try:
        if suffix in (".mhd", ".nhdr"):
            out += [p.with_suffix(s) for s in (".raw", ".zraw", ".raw.gz")]
            out += _named_data_files(p) if p.is_file() else []  # never open a FIFO
        if p.is_dir() or suffix in VIDEO_SUFFIXES:
            out += [p / "frames.json"] if p.is_dir() else \
                [p.with_suffix(".json"), p.with_name(p.name + ".json")]
            sc = sidecar_path(p)
            out += [sc] if sc is not None else []
        if p.is_dir():
            out += [f for f in p.iterdir()]
    except OSError:  # unreadable: reading it will say so
        pass
    return tuple(out)


def _named_data_files(header: Path) -> list[Path]:
    """The data files a MetaImage (``ElementDataFile = ...``) or detached NRRD (``data
    file: ...``) header names, read from its first 64 KiB."""
    import re

    with open(header, "rb") as fh:
        text = fh.read(1 << 16).decode("utf-8", "replace")
    names = re.findall(r"^\s*(?:ElementDataFile\s*=|data ?file\s*:)\s*(.+?)\s*$", text,
                       re.MULTILINE | re.IGNORECASE)
    out = []
    for n in names:
        for part in [n, *n.split()]:
            q = Path(part)
            out.append(q if q.is_absolute() else header.parent / q)
    return out


def _check_method(args) -> None:
    """Fill in the default method and features of ``args.tracker`` and check the method."""
    from ..trackers import DEFAULT_FEATURES, DEFAULT_METHODS, tracker_methods

    args.method = args.method or DEFAULT_METHODS[args.tracker]
    if args.model and args.features == "classical":
        raise CLIError("track: --model gives learned features; it does not go with --features "
                       "classical (leave --features out, or give learned)")
    # a model given is a learned source
    args.features = args.features or ("learned" if args.model else DEFAULT_FEATURES[args.tracker])
    if args.method not in tracker_methods(args.tracker):
        raise CLIError(f"track: tracker {args.tracker!r} has no method {args.method!r}; "
                       f"choose one of {', '.join(tracker_methods(args.tracker))}")


def _track_params(args):
    """``--param`` settings as the tracker's parameter class (None without any)."""
    from ..trackers import tracker_params

    if not args.param:
        return None
    try:
        return tracker_params(args.tracker, args.param, args.method)
    except (ValueError, TypeError) as exc:
        raise CLIError(f"track: --param: {exc}") from None


def _load(args):
    """The recording as a sequence; bad input becomes one CLIError line."""
    import numpy as np

    import synth

    from ..io import RecordingError, load_recording, parse_crop, parse_spacing

    try:
        spacing = None if args.spacing is None else parse_spacing(args.spacing)
        crop = None if args.crop is None else parse_crop(args.crop)
        is_npz = Path(args.file).suffix.lower() == ".npz"
        modality = None if is_npz or args.tracker == "volume" else args.tracker
        seq = load_recording(args.file, modality=modality, spacing_mm=spacing, crop=crop,
                             fps=args.fps)
    except (RecordingError, synth.SequenceFileError) as exc:
        raise CLIError(str(exc)) from None
    for note in seq.meta.get("warnings", []):
        print(f"needlenet: warning: {note}", file=sys.stderr)
    if seq.meta.get("format") == "plus" and args.spacing is None and \
            np.allclose(seq.spacing_mm, 1.0):
        print(f"needlenet: note: {args.file} says ElementSpacing = 1 (PLUS's default, pixels); "
              "pass --spacing if a pixel is not 1 mm", file=sys.stderr)
    return seq


def _make_tracker(args, params):
    from ..trackers import make_tracker

    kw = {"seed": args.seed}
    if params is not None:
        kw["params"] = params
    if args.angle is not None:
        kw["expected_angle_deg"] = args.angle
    try:
        return make_tracker(args.tracker, args.method, args.features, args.model, **kw)
    except (ValueError, FileNotFoundError) as exc:
        raise CLIError(f"track: {exc}") from None


def _check_model_grid(tracker, seq) -> None:
    """A learned model's grid fits the recording's frames (see
    :meth:`~needlenet.features.LearnedFeatures.check_frame_size`), checked before tracking."""
    from ..features import LearnedFeatures, ModelError

    features = getattr(tracker, "features", None)
    if isinstance(features, LearnedFeatures):
        try:
            features.check_frame_size(seq.images.shape[1:], seq.spacing_mm)
        except ModelError as exc:
            raise CLIError(f"track: {exc}") from None


def _open_stream(args):
    if args.igtl is None:
        return None
    from ..io import IGTLStreamer, StreamError

    try:
        streamer = IGTLStreamer(args.igtl, host=args.igtl_host)
    except StreamError as exc:
        raise CLIError(f"--igtl: {exc}") from None
    print(f"OpenIGTLink: serving on {streamer.host}:{streamer.port}", file=sys.stderr)
    if args.igtl_wait > 0 and not streamer.wait_for_client(args.igtl_wait):
        print(f"OpenIGTLink: no client after {args.igtl_wait:g} s; tracking anyway (frames are "
              "sent once a client connects)", file=sys.stderr)
    return streamer


def _run_tracker(args, tracker, seq) -> list:
    """Every frame through ``tracker`` (paced with ``--realtime``, streamed with ``--igtl``):
    the estimates."""
    import time

    import numpy as np

    from synth import Progress

    from ..io import MAX_GAP_S
    from ..trackers import frames_from_sequence

    streamer = _open_stream(args)
    bar = Progress(seq.n_frames, f"track {args.tracker}/{args.method}", not args.quiet)
    estimates = []
    ts = np.asarray(seq.timestamps_s, float)
    start = time.perf_counter()
    try:
        for i, frame in enumerate(frames_from_sequence(seq)):
            if args.realtime:  # the reader allows pauses of up to an hour between frames
                time.sleep(min(max(0.0, (ts[i] - ts[0]) - (time.perf_counter() - start)),
                               MAX_GAP_S))
            est = tracker.update(frame)
            estimates.append(est)
            bar.update()
            if streamer is not None:
                streamer.send_frame(frame.image, seq.spacing_mm, est.tip_mm, est.direction,
                                    est.axis_point_mm, est.status, origin=seq.origin_mm,
                                    probe_pose=None if seq.probe_pose is None
                                    else seq.probe_pose[i], timestamp=None)
    finally:
        if streamer is not None:
            streamer.close()
            print(f"OpenIGTLink: sent {streamer.frames_sent} frames, skipped "
                  f"{streamer.frames_skipped} (no client)", file=sys.stderr)
    return estimates


def _model_grid(tracker) -> dict:
    """For learned features: the grid the model ran on and the recording's speckle that chose
    it (the model's own grid where the model records no training speckle)."""
    from ..features import LearnedFeatures

    f = getattr(tracker, "features", None)
    if not isinstance(f, LearnedFeatures):
        return {}
    out = {"model_grid_mm": round(float(f.spacing_mm[0]), 4)}
    if f.recording_speckle_mm is not None:
        out["speckle_widths_mm"] = [round(v, 3) for v in f.recording_speckle_mm]
        out["training_speckle_cell_mm"] = f.speckle_cell_mm
    return out


def _report(args, seq, estimates, out_json, overlay, out_plus, model_grid=None) -> None:
    """The summary on stdout, then the ``--json``, ``--overlay`` and ``--out-plus`` files."""
    from ..eval import evaluate

    metrics = evaluate(args.tracker, estimates, seq)["summary"] if seq.has_labels else None
    geometry = {"spacing_mm": [round(float(v), 6) for v in seq.spacing_mm]}
    if isinstance(seq.meta, dict) and seq.meta.get("crop") is not None:
        geometry["crop"] = seq.meta["crop"]  # the image area read (given, or the file's)
    write_summary(args, estimates, out_json, metrics, {**geometry, **(model_grid or {})})
    if overlay is not None:
        from ..io import write_overlay

        write_overlay(overlay, seq, estimates)
        print(f"wrote {overlay}")
    if out_plus is not None:
        from ..io import RecordingError, save_plus_sequence

        try:
            save_plus_sequence(seq, out_plus, estimates, overwrite=args.overwrite)
        except RecordingError as exc:
            raise CLIError(f"--out-plus: {exc}") from None
        print(f"wrote {out_plus}")


MAX_REASONS = 3  # the reasons the summary lists


def reason_counts(estimates) -> list[tuple[str, int]]:
    """The reasons the tracker gave for frames it reported without a needle, each with its
    number of frames, most frequent first: the text with its figures as ``N`` (the lengths and
    distances of one cause differ from frame to frame)."""
    import re
    from collections import Counter

    texts = [re.sub(r"\d+(?:\.\d+)?", "N", e.reason) for e in estimates
             if e.status.value != "tracking" and e.reason]
    return sorted(Counter(texts).items(), key=lambda kv: (-kv[1], kv[0]))


def write_summary(args, estimates, out_json, metrics=None, about=None) -> None:
    """The summary on stdout (``about`` the recording and the model: its spacing, the grid
    the model ran on; the paper's ``metrics`` of a labelled recording, else the latency),
    and the ``--json`` file with every frame's estimate."""
    import json

    from ..eval import latency_summary

    summary = {"file": str(args.file), "tracker": args.tracker, "method": args.method,
               "features": args.features, "frames": len(estimates), **(about or {})}
    summary.update(metrics if metrics is not None else latency_summary(estimates))
    statuses = [e.status.value for e in estimates]
    summary["status_counts"] = {s: statuses.count(s) for s in sorted(set(statuses))}
    # on stdout too, as plain numbers: how often the tracker saw the needle, and how often it
    # said it did not (a recording without labels has no other figure of what it found)
    for s in ("tracking", "lost", "searching"):
        summary[f"frames_{s}"] = statuses.count(s)
    # the in-plane `line` tracker's tips read where an advancing needle gained echo (its map
    # showed no needle line there)
    moved = sum(bool(getattr(e.details, "tip_from_motion", False)) for e in estimates)
    if moved:
        summary["frames_tip_from_motion"] = moved
    # why the frames without a needle had none: the most frequent reasons first
    summary["reasons"] = [f"{n} frame{'s' * (n != 1)}: {text}"
                          for text, n in reason_counts(estimates)[:MAX_REASONS]]
    summary = finite_json(summary)
    print(json.dumps({k: v for k, v in summary.items() if not isinstance(v, dict)}, indent=1,
                     allow_nan=False))
    if out_json is not None:
        from ..io import atomic_write

        text = json.dumps(finite_json({"frames": [e.to_json() for e in estimates],
                                       "summary": summary}), indent=1, allow_nan=False)
        atomic_write({out_json: lambda fh: fh.write(text.encode())}, overwrite=True)
        print(f"wrote {out_json}")


def finite_json(obj):
    """``obj`` (dicts, lists, numbers, numpy scalars and arrays) as plain JSON values with
    every NaN or infinity as None (``null``): a metric that is undefined (no frame tracked)
    or a score a tracker could not compute is reported as missing, never as ``NaN``, which
    is not JSON."""
    import math

    import numpy as np

    if isinstance(obj, dict):
        return {str(k): finite_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite_json(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)
