"""Case families: models, --param, absurd options, output paths, synth options."""

from __future__ import annotations

import dataclasses

from ._base import CLEAN, INPUTS, MODELS, Base, _case, make_model, mutate_bytes, pick

MODEL_VARIANTS = (
    ("op", "nan"), ("op", "nan_bright"), ("op", "inf"), ("op", "huge"), ("op", "up2"),
    ("op", "up64"), ("op", "down4"), ("op", "flatten"), ("op", "int64"), ("op", "double"),
    ("op", "double_in"), ("op", "two_outputs"), ("op", "badop"), ("op", "slow"),
    ("rank", 3), ("rank", 5), ("rank", 2), ("fixed", None), ("noshape", None),
    ("channels", 1), ("channels", 3), ("names", "in"), ("names", "out"),
    ("meta", "modality"), ("meta", "spacing_mm"), ("meta", "normalization"),
    ("meta", "output_stride"), ("meta", "input_multiple"), ("meta", "target_reference"),
    ("drop", "modality"), ("drop", "spacing_mm"), ("drop", "normalization"),
    ("file", "cut"), ("file", "flip"), ("file", "empty"), ("file", "text"), ("file", "npz"),
    ("file", "dir"), ("file", "missing"), ("ok", None),
)
META_VALUES = {
    "modality": ("axial", "volume", "bogus", "", "inplane "),
    "spacing_mm": ("nope", "[0.2]", "[0, 0.2]", "[1e9, 1e9]", "[NaN, NaN]", '"ab"', "null",
                   "{}", "1e400", "[0.2, 0.2, 0.2]", "[1e-300, 0.2]", "[true, false]",
                   "[0.005, 0.005, 0.005]", "[0.005, 0.005]", "[5, 5, 5]"),
    "normalization": ("nope", "{}", '{"mode": "fixed"}',
                      '{"mode": "bogus", "scale": 1, "mean": 0, "std": 1}',
                      '{"mode": "robust", "scale": 1, "mean": 0, "std": 1, "clip": "x"}',
                      '{"mode": "robust", "scale": 1, "mean": 0, "std": 1, "clip": [NaN, 1]}',
                      '{"mode": "robust", "scale": 1, "mean": 0, "std": 1, "zero_value": "x"}',
                      '{"mode": "median", "scale": 1, "mean": 1e308, "std": 1e-308}',
                      '{"mode": "fixed", "scale": 1e308, "mean": 0, "std": 1e-300}',
                      '{"mode": "fixed", "scale": NaN, "mean": 0, "std": 1}', "[1, 2]",
                      '{"mode": ["fixed"], "scale": 1, "mean": 0, "std": 1}'),
    "output_stride": ("0", "-1", "1e9", "x", "16", "17", "2.5"),
    "input_multiple": ("0", "1000", "x", "256", "255", "128", "-4"),
    "target_reference": ("bogus", "", "wall"),
}


def fam_model(rng, base: Base) -> dict:
    modality = pick(rng, ("inplane", "inplane", "axial", "volume"))
    inp = {"inplane": pick(rng, ("i.npz", "i.seq.mha")), "axial": "a.npz",
           "volume": "v.npz"}[modality]
    kind, arg = pick(rng, MODEL_VARIANTS)
    files = base.input_files(inp)
    name = "model.onnx"
    what = f"{modality} model: {kind} {arg}"
    nd = 3 if modality == "volume" else 2
    expect = CLEAN
    if kind == "op":
        files[name] = make_model(modality, op=arg)
    elif kind == "rank":
        files[name] = make_model(modality, in_shape=["N", 1] + ["S"] * (arg - 2))
    elif kind == "fixed":
        files[name] = make_model(modality, in_shape=[1, 1] + [64] * nd)
    elif kind == "noshape":
        files[name] = make_model(modality, in_shape="none")
    elif kind == "channels":
        files[name] = make_model(modality, channels=arg)
    elif kind == "names":
        files[name] = make_model(modality, **({"in_name": "x"} if arg == "in" else
                                              {"out_name": "y"}))
    elif kind == "meta":
        v = pick(rng, META_VALUES[arg])
        if arg == "modality" and v == "":
            v = "x"
        files[name] = make_model(modality, meta={arg: v})
        what += f" = {v!r}"
    elif kind == "drop":
        files[name] = make_model(modality, drop=(arg,))
    elif kind == "file":
        good = base.files[MODELS[modality]]
        if arg == "cut":
            at = int(rng.integers(len(good)))
            files[name] = good[:at]
            what += f" at {at} of {len(good)}"
        elif arg == "flip":
            files[name], w = mutate_bytes(good, rng)
            what += f" ({w})"
        elif arg == "empty":
            files[name] = b""
        elif arg == "text":
            files[name] = b"not a model\n"
        elif arg == "npz":
            files[name] = base.files["i.npz"]
        elif arg == "dir":
            files[name + "/"] = b""
    else:
        files[name] = base.files[MODELS[modality]]
        expect = ("ok",)
    argv = ["track", "{d}/" + inp, "--quiet", "--json", "{d}/out.json", "--model",
            "{d}/" + name]
    if rng.random() < 0.3:
        argv += ["--features", "learned"]
    return _case("model", what, argv, files, expect=expect)


PARAM_VALUES = ("nan", "inf", "-inf", "-1", "0", "1", "1e9", "1e300", "-1e300", "x", "",
                "true", "none", "1.5", "2147483648", "99999999999999999999", "1,2", "3",
                "1e-300", "-0", "0.5,nan", "1,2,3,4,5")
# tracker, method, input
PARAM_TARGETS = (("inplane", "kf", "i.npz"), ("inplane", "pf+f", "i.npz"),
                 ("inplane", "df", "i.npz"), ("inplane", "line", "i.npz"),
                 ("inplane", "om", "i.npz"), ("inplane", "kfv", "i.npz"),
                 ("volume", "roi-rk", "v.npz"), ("volume", "ransac", "v.npz"),
                 ("volume", "chatelain", "v.npz"), ("axial", "carriere", "a.npz"))


def param_fields(tracker: str, method: str) -> list[str]:
    """Every real ``--param`` name of the tracker that runs ``method``: the fields of its
    parameter dataclass and, as NAME.FIELD, of the dataclasses it nests."""
    import importlib

    from needlenet.trackers._registry import PARAMS, tracker_class

    cls = tracker_class(tracker, method)
    pcls = getattr(importlib.import_module(cls.__module__), PARAMS[cls.__name__])
    out = []
    base = pcls()
    for f in dataclasses.fields(pcls):
        v = getattr(base, f.name)
        if dataclasses.is_dataclass(v):
            out += [f"{f.name}.{g.name}" for g in dataclasses.fields(v)]
        else:
            out.append(f.name)
    return out


def fam_param(rng, base: Base) -> dict:
    tracker, method, inp = pick(rng, PARAM_TARGETS)
    names = param_fields(tracker, method)
    settings = []
    for _ in range(int(pick(rng, (1, 1, 1, 2, 3)))):
        if rng.random() < 0.1:
            settings.append(pick(rng, ("noequals", "=5", "bogus=1", "a.b.c=1", f" {names[0]} =3",
                                       f"{names[0]}.x=1", "axis=3", "insertion=1", "pf=2",
                                       "frangi.c=x", f"{names[-1]}==1")))
        else:
            settings.append(f"{pick(rng, names)}={pick(rng, PARAM_VALUES)}")
    argv = ["track", "{d}/" + inp, "--quiet", "--json", "{d}/out.json", "--tracker", tracker,
            "--method", method]
    if rng.random() < 0.5:
        argv += ["--features", "classical"]
    for s in settings:
        argv += ["--param", s]
    return _case("param", f"{tracker}/{method}: {' '.join(settings)}", argv,
                 base.input_files(inp))


OPTION_VALUES = {
    "--spacing": ("0", "-1", "nan", "inf", "1e-9", "1e9", "0.1,0.1,0.1", "0.1,", ",", "", "x",
                  "1e308,1e308", "0.1 0.1", "0.005", "5", "0.1,nan", "1e-300", "0.1,0.1,0.1,0.1",
                  "-0.1,0.1", "0.2,0.05"),
    "--fps": ("0", "-1", "nan", "inf", "1e-300", "1e300", "x", "", "0.1", "1000", "1001",
              "-inf", "20"),
    "--crop": ("0,0,1,1", "-1,0,10,10", "0,0,100000,100000", "0,0,0,0", "1,2,3", "a,b,c,d",
               "1.5,2,3,4", "0,0,99999999999999999999,10", "", "10,10,50,50", "0,0,2,2",
               "118,98,2,2", "0,0,120,100", "-99999999999999999999,0,5,5"),
    "--angle": ("nan", "inf", "-1", "91", "45", "x", "1e309", "0", "90", "-0"),
    "--tracker": ("volume", "axial", "inplane", "bogus"),
    "--method": ("bogus", "ransac", "carriere", "df", "line", "pfv+f", ""),
    "--features": ("bogus", "classical", "learned", ""),
    "--seed": ("-1", "9223372036854775808", "x", "1.5", "0", "9223372036854775807"),
    "--igtl": ("-1", "70000", "x", "65536"),
}


def fam_options(rng, base: Base) -> dict:
    inp = pick(rng, ("i.npz", "a.npz", "v.npz", "i.seq.mha", "bare", "bare.avi", "i.seq.nrrd",
                     "v.seq.mha", "frames"))
    opts = []
    for _ in range(int(pick(rng, (1, 1, 2, 3)))):
        opt = pick(rng, sorted(OPTION_VALUES) + ["--spacing", "--fps", "--crop", "--realtime",
                                                  "--igtl-host", "--igtl-wait", "--unknown",
                                                  "--file"])
        if opt == "--realtime":
            opts += ["--realtime", "--fps", "1000"]
        elif opt == "--igtl-host":
            opts += ["--igtl", "0", "--igtl-host", pick(rng, ("bogus-interface", "",
                                                              "256.1.1.1", "lo"))]
        elif opt == "--igtl-wait":
            opts += ["--igtl", "0", "--igtl-wait", pick(rng, ("-1", "nan", "0.05", "x"))]
        elif opt == "--unknown":
            opts += [pick(rng, ("--bogus", "-x", "--json", "--"))]
        elif opt == "--file":
            opts += [pick(rng, ("{d}/missing.npz", "{d}/x.txt", "{d}", "", "{d}/x"))]
        else:
            opts += [opt, pick(rng, OPTION_VALUES[opt])]
    extra = list(INPUTS[inp][2])
    if "--spacing" in opts:
        extra = [a for a in extra if a not in ("--spacing", "0.1")]
    if "--fps" in opts:
        extra = [a for a in extra if a not in ("--fps", "20")]
    argv = ["track", "{d}/" + inp, "--quiet", "--json", "{d}/out.json", *extra, *opts]
    files = base.input_files(inp)
    if "{d}/x.txt" in opts:
        files["x.txt"] = b"text"
    return _case("options", f"{inp}: {' '.join(opts)}", argv, files)


def fam_output(rng, base: Base) -> dict:
    """Output paths: directories, the input and the files beside it, missing or unwritable
    directories, existing files with and without --overwrite (then they must be unchanged),
    symlinks, names too long."""
    inp = pick(rng, ("i.npz", "i.seq.mha", "i.mhd", "iz.mhd", "i.nhdr", "frames", "clip.avi",
                     "v.npz"))
    files = base.input_files(inp)
    option = pick(rng, ("--json", "--json", "--overlay", "--out-plus", "--out-plus"))
    suffix = {"--json": ".json", "--overlay": pick(rng, (".gif", ".mp4", ".avi")),
              "--out-plus": pick(rng, (".seq.mha", ".mhd"))}[option]
    overwrite = rng.random() < 0.5
    choice = pick(rng, ("dir", "input", "beside", "sidecar", "missing_dir", "parent_file",
                        "proc", "exists", "exists", "exists_companion", "long", "symlink_input",
                        "symlink_dangling", "readonly_dir", "suffix", "empty", "fine", "dotdot",
                        "data_file_named_like_output", "hardlink_input", "newline", "dev_null"))
    name = "r" + suffix
    outputs: tuple[str, ...] = ()
    expect = CLEAN
    links: dict[str, str] = {}
    modes: dict[str, int] = {}
    path = "{d}/" + name
    companions = (name, name[:-4] + ".zraw") if suffix == ".mhd" else (name,)
    what = f"{option} "
    if choice == "dir":
        files[name + "/"] = b""
        what += "an existing directory"
        expect = ("clean-error",)
    elif choice == "input":
        path = "{d}/" + (INPUTS[inp][0][0] if inp not in ("frames",) else "frames")
        what += "the input itself"
        expect = ("clean-error",)
    elif choice == "beside":
        rels = [r for r in INPUTS[inp][0] if r != INPUTS[inp][0][0]] or list(INPUTS[inp][0])
        path = "{d}/" + pick(rng, rels)
        what += f"a file of the input ({path[4:]})"
        expect = ("clean-error",)
    elif choice == "sidecar":
        if inp == "clip.avi":
            path = "{d}/clip.json"
        elif inp == "frames":
            path = "{d}/frames/frames.json"
        else:  # no sidecar: a file of the user's beside the input
            path = "{d}/" + INPUTS[inp][0][0] + ".json"
            files[INPUTS[inp][0][0] + ".json"] = b'{"precious": true}'
        what += f"the input's sidecar or a file next to it ({path[4:]})"
        if inp in ("clip.avi", "frames") or option != "--json":
            expect = ("clean-error",)
        elif overwrite:
            outputs = (path[4:],)
        else:
            expect = ("clean-error",)
    elif choice == "data_file_named_like_output":
        # a detached header whose data file is named like the output's companion
        if inp in ("i.mhd", "iz.mhd", "i.nhdr"):
            data_rel = INPUTS[inp][0][1]
            files["r.zraw" if suffix == ".mhd" else "r.raw"] = files.pop(data_rel)
            hdr = files[inp].decode()
            new_name = "r.zraw" if suffix == ".mhd" else "r.raw"
            hdr = hdr.replace(data_rel, new_name)
            files[inp] = hdr.encode()
            what += f"next to an input whose data file is {new_name}"
            path = "{d}/" + ("r.mhd" if suffix == ".mhd" else "r" + suffix)
            expect = ("clean-error",) if option == "--out-plus" and suffix == ".mhd" else CLEAN
            if expect == CLEAN:
                outputs = companions
        else:
            outputs = companions
            what += "(plain)"
    elif choice == "missing_dir":
        path = "{d}/no/such/dir/" + name
        what += "in a missing directory"
        expect = ("clean-error",)
    elif choice == "parent_file":
        files["afile"] = b"x"
        path = "{d}/afile/" + name
        what += "under a regular file"
        expect = ("clean-error",)
    elif choice == "proc":
        path = pick(rng, ("/proc/" + name, "/sys/" + name, "/proc/self/" + name))
        what += f"in {path.rsplit('/', 1)[0]}"
        expect = ("clean-error",)
    elif choice in ("exists", "exists_companion"):
        rel = companions[-1] if choice == "exists_companion" else name
        files[rel] = b"precious user file\n"
        what += f"an existing {rel}" + (" with --overwrite" if overwrite else "")
        if overwrite:
            outputs = companions
        else:
            expect = ("clean-error",)
    elif choice == "long":
        stem = "x" * int(pick(rng, (240, 250, 256, 300, 5000)))
        path = "{d}/" + stem + suffix
        outputs = (stem + suffix,) + ((stem + ".zraw",) if suffix == ".mhd" else ())
        what += f"a name of {len(stem + suffix)} characters"
    elif choice == "symlink_input":
        links[name] = "{d}/" + INPUTS[inp][0][-1]
        what += "a symlink to an input file"
        expect = ("clean-error",)
    elif choice == "symlink_dangling":
        links[name] = "{d}/nowhere/x"
        what += "a dangling symlink"
        outputs = companions
    elif choice == "readonly_dir":
        files["ro/"] = b""
        modes["ro"] = 0o555
        path = "{d}/ro/" + name
        outputs = tuple("ro/" + c for c in companions)
        what += "in a read-only directory"
    elif choice == "suffix":
        path = "{d}/r" + pick(rng, (".txt", ".JSON", ".npz", ".seq.nrrd", "", ".gif.json",
                                    ".MHA", ".Gif"))
        outputs = (path[4:],) + ((path[4:-4] + ".zraw",) if path.lower().endswith(".mhd")
                                 else ())
        what += f"suffix {path[5:]!r}"
    elif choice == "empty":
        path = pick(rng, ("", " ", "."))
        what += f"{path!r}"
        expect = ("clean-error",)
    elif choice == "dotdot":
        path = "{d}/sub/../" + name
        files["sub/"] = b""
        outputs = companions
        what += "via sub/.."
    elif choice == "hardlink_input":
        links[name] = "{d}/" + INPUTS[inp][0][0]
        what += "a symlink to the input"
        expect = ("clean-error",)
    elif choice == "newline":
        path = "{d}/r\nx" + suffix
        outputs = ("r\nx" + suffix,) + (("r\nx.zraw",) if suffix == ".mhd" else ())
        what += "a name with a newline"
    elif choice == "dev_null":
        path = "/dev/null"
        what += "/dev/null"
        expect = ("clean-error",)
    else:
        outputs = companions
        what += "a fine new file"
        expect = ("ok",)
    argv = ["track", "{d}/" + inp, "--quiet", *INPUTS[inp][2], "--features", "classical"]
    if option == "--json":
        argv += ["--json", path]
    else:
        argv += ["--json", "{d}/out.json", option, path]
        outputs = outputs + ("out.json",)
    if overwrite:
        argv.append("--overwrite")
    return _case("output", what, argv, files, outputs=outputs, expect=expect, links=links,
                 modes=modes)


SYNTH_SMALL = {"inplane": ["--param", "width_mm=8", "--param", "depth_mm=6", "--param",
                           "start_length_mm=3"],
               "axial": ["--param", "width_mm=8", "--param", "depth_mm=8"],
               "volume": ["--param", "output_size=24"]}
SYNTH_PARAMS = ("width_mm", "depth_mm", "spacing_mm", "frames", "gauge", "frame_rate_hz",
                "dynamic_range_db", "needle_echo", "noise_db", "scatterers_per_cell", "side",
                "background", "angle_deg", "speed_mm_s", "start_length_mm", "stop_length_mm",
                "output_size", "step_mm", "insertion_mm", "vessels", "shadows", "bogus",
                "entry_offset_range_mm", "cr", "out_of_plane_deg", "volume_rate_hz",
                "alpha_deg", "beta_deg", "needle_free", "tissue_motion_mm")
SYNTH_VALUES = ("nan", "inf", "-1", "0", "1e9", "1e-9", "x", "", "true", "none", "1,2",
                "99999999999999999999", "1e300", "-1e300", "2", "0.5", "2000", "100001")


def fam_synth(rng, base: Base) -> dict:
    scen = pick(rng, ("inplane", "inplane", "axial", "axial", "volume"))
    out_name = pick(rng, ("s.npz", "s.npz", "s.seq.mha", "s.mhd"))
    frames = "1" if scen == "volume" else "2"
    argv = ["synth", scen, "--out", "{d}/" + out_name, "--frames", frames, "--quiet",
            *SYNTH_SMALL[scen]]
    files: dict[str, bytes] = {}
    outputs = (out_name,) + (("s.zraw",) if out_name == "s.mhd" else ())
    expect = CLEAN
    choice = pick(rng, ("param", "param", "param", "frames", "cr", "speed", "angle", "out",
                        "preview", "format", "scenario", "background", "list", "ok"))
    what = f"synth {scen} -> {out_name}: "
    if choice == "param":
        k, v = pick(rng, SYNTH_PARAMS), pick(rng, SYNTH_VALUES)
        argv += ["--param", f"{k}={v}"]
        what += f"--param {k}={v}"
    elif choice in ("frames", "cr", "speed", "angle"):
        v = pick(rng, ("0", "-1", "nan", "inf", "1e9", "x", "", "1.5", "1e-9", "100001",
                       "99999999999999999999"))
        if choice == "frames":
            argv[argv.index("--frames") + 1] = v
        else:
            argv += [f"--{choice}", v]
        what += f"--{choice} {v}"
    elif choice == "out":
        sub = pick(rng, ("dir", "exists", "missing", "proc", "suffix", "companion", "empty"))
        o = argv.index("--out") + 1
        if sub == "dir":
            files[out_name + "/"] = b""
            expect = ("clean-error",)
        elif sub == "exists":
            files[out_name] = b"precious"
            if rng.random() < 0.5:
                argv.append("--overwrite")
            else:
                expect = ("clean-error",)
        elif sub == "companion":
            argv[o] = "{d}/s.mhd"
            outputs = ("s.mhd", "s.zraw")
            files["s.zraw"] = b"precious"
            expect = ("clean-error",)
        elif sub == "missing":
            argv[o] = "{d}/missing/" + out_name
            expect = ("clean-error",)
        elif sub == "proc":
            argv[o] = "/proc/" + out_name
            expect = ("clean-error",)
        elif sub == "suffix":
            argv[o] = "{d}/s" + pick(rng, (".txt", ".NPZ", ".nrrd", ""))
            outputs = (argv[o][4:],)
        else:
            argv[o] = pick(rng, ("", "."))
            expect = ("clean-error",)
        what += f"--out {sub}"
    elif choice == "preview":
        v = pick(rng, ("{d}/p.png", "{d}/p.jpg", "{d}/missing/p.png", "{d}/" + out_name,
                       "{d}/pdir.png"))
        if v.endswith("pdir.png"):
            files["pdir.png/"] = b""
        argv += ["--preview", v]
        outputs = outputs + ("p.png",)
        what += f"--preview {v[4:]}"
    elif choice == "format":
        v = pick(rng, ("npz", "plus", "bogus"))
        argv += ["--format", v]
        what += f"--format {v}"
    elif choice == "scenario":
        argv[1] = pick(rng, ("bogus", "", "--list", "servo"))
        what += f"scenario {argv[1]!r}"
    elif choice == "background":
        argv += ["--background", pick(rng, ("bogus", "homogeneous"))]
        what += f"--background {argv[-1]}"
    elif choice == "list":
        argv = ["synth", "--list"]
        what = "synth --list"
        expect = ("ok",)
    else:
        what += "as given"
        expect = ("ok",)
    return _case("synth", what, argv, files, outputs=outputs, expect=expect)
