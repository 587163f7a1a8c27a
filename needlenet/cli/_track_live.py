"""``needlenet track igtl://HOST[:PORT][/DEVICE]``: track the frames a PLUS Server (or any
OpenIGTLink server) streams, as they arrive, and stream the results back with ``--igtl``.

The stream has no labels and no end but a pause: it is tracked until no frame comes for
``--igtl-idle`` seconds, or Ctrl-C; then the summary and ``--json`` are written as for a
file. A frame of another size or spacing (the scanner's depth changed) starts the tracker
anew. ``--overlay`` and ``--out-plus`` need the frames kept: record the stream (PLUS's
capture, or Slicer's Sequences module) and track the file.
"""

from __future__ import annotations

import sys
import time

from ._common import CLIError


def run_live(args, out_json, overlay, out_plus) -> int:
    from ..io import StreamError
    from ..io._igtl_source import IGTLSource, parse_igtl_url
    from ._track import (
        _check_method,
        _make_tracker,
        _model_grid,
        _open_stream,
        _track_params,
        write_summary,
    )

    if overlay is not None or out_plus is not None or args.realtime:
        raise CLIError("track: --overlay, --out-plus and --realtime read a recording file; "
                       "record the OpenIGTLink stream (PLUS, or Slicer's Sequences module) "
                       "and track the file")
    for name in ("spacing", "crop", "fps"):
        if getattr(args, name) is not None:
            raise CLIError(f"track: --{name} is for recording files; an OpenIGTLink IMAGE "
                           "carries its own spacing and time")
    try:
        host, port, device = parse_igtl_url(args.file)
    except StreamError as exc:
        raise CLIError(f"track: {exc}") from None
    args.tracker = args.tracker or "inplane"
    if args.tracker == "volume":
        raise CLIError("track: the volume trackers read recorded files; OpenIGTLink input is "
                       "2D frames (--tracker inplane or axial)")
    _check_method(args)
    params = _track_params(args)
    tracker = _make_tracker(args, params)
    streamer = _open_stream(args)
    estimates: list = []
    geometry = None
    last_note = time.monotonic()
    try:
        with IGTLSource(host, port, device, connect_s=args.igtl_connect,
                        idle_s=args.igtl_idle) as source:
            if not args.quiet:
                print(f"OpenIGTLink: receiving {device!r} from {host}:{port}", file=sys.stderr)
            for frame in source.frames():
                g = (frame.grid.shape, frame.grid.spacing_mm)
                if geometry is not None and g != geometry:
                    tracker = _make_tracker(args, params)  # another depth or probe: anew
                    print(f"OpenIGTLink: frame {frame.index} is {g[0][1]}x{g[0][0]} pixels of "
                          f"{g[1][0]:.4g} x {g[1][1]:.4g} mm; the tracker starts anew",
                          file=sys.stderr)
                geometry = g
                est = tracker.update(frame)
                estimates.append(est)
                if streamer is not None:
                    streamer.send_frame(frame.image, frame.grid.spacing_mm, est.tip_mm,
                                        est.direction, est.axis_point_mm, est.status,
                                        probe_pose=frame.probe_pose, timestamp=frame.t)
                if not args.quiet and time.monotonic() - last_note >= 2.0:
                    last_note = time.monotonic()
                    print(f"OpenIGTLink: {len(estimates)} frames, {est.status.value}",
                          file=sys.stderr)
    except StreamError as exc:
        raise CLIError(f"track: {exc}") from None
    except KeyboardInterrupt:
        print("OpenIGTLink: stopped", file=sys.stderr)
    finally:
        if streamer is not None:
            streamer.close()
    if not estimates:
        raise CLIError(f"track: no frame from {args.file}")
    if not args.quiet:
        print(f"OpenIGTLink: tracked {len(estimates)} frames (the stream paused for "
              f"{args.igtl_idle:g} s)", file=sys.stderr)
    write_summary(args, estimates, out_json, None,
                  {"spacing_mm": [round(float(v), 6) for v in geometry[1]],
                   **_model_grid(tracker)})
    return 0
