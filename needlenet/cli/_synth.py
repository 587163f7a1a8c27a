"""``needlenet synth``: simulate a labelled needle-insertion sequence and write it."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, check_output, check_plus_output, seed

MAX_FRAMES = 100_000  # an hour at 25 frames/s


def add_parser(sub) -> None:
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
    p.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
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
    p.set_defaults(func=run)


def run(args) -> int:
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
        raise CLIError("synth: --out FILE.npz (or FILE.seq.mha) is required")
    fmt, out = _output(args)
    preview = check_output(args.preview, ".png", args.overwrite, "preview")
    overrides = _overrides(args, synth.SCENARIOS[args.scenario])
    try:
        params = synth.scenario_params(args.scenario, **overrides)  # validate before any work
        if hasattr(params, "imaging"):
            params.imaging()  # the scanner's settings the scenario derives, checked too
    except (ValueError, TypeError) as exc:
        raise CLIError(f"synth: {exc}") from None
    _check_readable(params)
    _check_size(params)
    seq = synth.generate(args.scenario, seed=args.seed, progress=not args.quiet, **overrides)
    if fmt == "plus":
        from ..io import RecordingError, save_plus_sequence

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


def _check_readable(params) -> None:
    """The numbers a sequence's meta records that its readers check (the insertion speed,
    the rotation depth: see :func:`needlenet.io._limits.check_meta_numbers`) and its frame
    rate are in their ranges, so that what synth writes, track reads."""
    import dataclasses

    from ..io import RecordingError, check_fps, check_meta_numbers

    try:
        check_meta_numbers({"params": {f.name: getattr(params, f.name)
                                       for f in dataclasses.fields(params)}}, "synth")
        for name in ("frame_rate_hz", "volume_rate_hz"):  # the frame times written
            if isinstance(getattr(params, name, None), (int, float)):
                check_fps(getattr(params, name), "synth", name)
    except RecordingError as exc:
        raise CLIError(str(exc).replace("synth: meta field params.", "synth: ")) from None


def _check_size(params) -> None:
    """A volume scenario's ``output_size`` makes frames of at most as many voxels as a 2D
    scenario's frame may have pixels (``synth._scenarios.MAX_FRAME_PIXELS``, which the 2D
    scenarios check themselves), and all the frames asked for fit this machine's memory."""
    from synth import MAX_FRAME_PIXELS

    from ..io import RecordingError, check_allocation

    n = getattr(params, "output_size", None)
    if isinstance(n, int) and not 1 <= n ** 3 <= MAX_FRAME_PIXELS:
        raise CLIError(f"synth: output_size={n} makes volumes of {n ** 3:.3g} voxels (at most "
                       f"{MAX_FRAME_PIXELS}, {round(MAX_FRAME_PIXELS ** (1 / 3))}^3)")
    frames = getattr(params, "frames", None)
    if isinstance(n, int):
        shape = (n, n, n)
    elif all(isinstance(getattr(params, k, None), (int, float))
             for k in ("spacing_mm", "width_mm", "depth_mm")):
        sp = params.spacing_mm
        shape = (params.depth_mm / sp, params.width_mm / sp)
    else:
        return
    if isinstance(frames, int):
        try:
            check_allocation((frames, *(max(int(s), 1) for s in shape)), 1, "synth",
                             "frames x frame size")
        except RecordingError as exc:
            raise CLIError(str(exc).replace("; damaged header?", "; ask for fewer frames"))\
                from None


def _field_default(f):
    import dataclasses

    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _overrides(args, cls) -> dict:
    """The scenario parameters the options and ``--param`` settings change; a setting of a
    field is read as the field's type (:func:`needlenet.settings.convert_setting`: a float
    field takes a finite number, an integer a whole one), an unknown name is left for the
    scenario to refuse by name."""
    import dataclasses
    import math

    from ..settings import convert_setting, parse_value

    fields = {f.name: f for f in dataclasses.fields(cls)}
    overrides = {}
    for item in args.param:
        if "=" not in item:
            raise CLIError(f"synth: --param {item!r}: expected NAME=VALUE")
        k, v = item.split("=", 1)
        k = k.strip()
        if k in fields:
            try:
                overrides[k] = convert_setting(k, v, _field_default(fields[k]), fields[k].type)
            except ValueError as exc:
                raise CLIError(f"synth: --param {k}: {exc}") from None
        else:
            overrides[k] = parse_value(v)
    for name in ("cr", "speed", "angle"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            raise CLIError(f"synth: --{name} {v}: expected a finite number")
    names = set(fields)
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
    frames = overrides.get("frames")
    if isinstance(frames, int) and not isinstance(frames, bool) and \
            not 1 <= frames <= MAX_FRAMES:
        raise CLIError(f"synth: frames {frames}: expected 1 to {MAX_FRAMES}")
    return overrides


def _output(args) -> tuple[str, Path]:
    """The output format (by ``--format`` or the suffix) and the checked output path."""
    suffix = Path(args.out).suffix.lower()
    fmt = args.format or ("plus" if suffix in (".mha", ".mhd") else "npz")
    if fmt == "plus":
        return fmt, check_plus_output(args.out, args.overwrite, "output")
    return fmt, check_output(args.out, ".npz", args.overwrite, "output")
