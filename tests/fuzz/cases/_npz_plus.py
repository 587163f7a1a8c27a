"""Case families: npz bytes and arrays, PLUS header fields and bytes, non-finite pixels."""

from __future__ import annotations

import io
import json
import re
import zipfile

import numpy as np

from ._base import (
    NPZ_INPUTS,
    PLUS_INPUTS,
    Base,
    _case,
    _deep_json,
    _nrrd_2d,
    _track,
    _track_any,
    edit_numbers,
    get_field,
    join_mha,
    mutate_bytes,
    pick,
    remove_field,
    set_field,
    split_mha,
)


def fam_npz_bytes(rng, base: Base) -> dict:
    inp = pick(rng, NPZ_INPUTS)
    data = base.files[inp]
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        infos = z.infolist()
    where = pick(rng, ("any", "member", "central"))
    if where == "member":
        info = pick(rng, infos)
        lo = info.header_offset
        hi = lo + 30 + len(info.filename) + info.compress_size
        what0 = f"in member {info.filename}"
    elif where == "central":
        lo, hi = min(len(data) - 22 - 46 * len(infos) * 2, len(data) - 1), len(data)
        lo = max(lo, 0)
        what0 = "in the zip directory"
    else:
        lo, hi, what0 = 0, len(data), "anywhere"
    new, what = mutate_bytes(data, rng, lo, hi)
    return _case("npz-bytes", f"{inp}: {what} ({what0})", _track(inp, rng), {inp: new})


def _npz(arrays: dict) -> bytes:
    """The arrays (or raw member bytes) as an .npz; members carry a fixed time stamp, so the
    same arrays give the same bytes (zipfile would stamp the current time)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for k, v in arrays.items():
            info = zipfile.ZipInfo(f"{k}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            if isinstance(v, bytes):
                zf.writestr(info, v)
                continue
            b = io.BytesIO()
            np.lib.format.write_array(b, np.asanyarray(v), allow_pickle=False)
            zf.writestr(info, b.getvalue())
    return buf.getvalue()


def _npy_header(shape, descr="|u1") -> bytes:
    h = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}".encode()
    h += b" " * (63 - len(h) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(h).to_bytes(2, "little") + h




def fam_npz_arrays(rng, base: Base) -> dict:
    """Structural edits of a sequence file: arrays removed, retyped, reshaped, made
    non-finite, forged headers, meta JSON edits."""
    k = pick(rng, ("i", "a", "v"))
    inp = f"{k}.npz"
    with np.load(io.BytesIO(base.files[inp])) as z:
        arrays = {n: z[n] for n in z.files}
    T = arrays["images"].shape[0]
    nd = arrays["images"].ndim - 1
    key = pick(rng, sorted(arrays))
    op = pick(rng, ("remove", "dtype", "shape", "nonfinite", "value", "meta", "meta", "forge",
                    "scalar", "images", "labels"))
    a = arrays.get(key)
    what = f"{inp}: "
    if op == "remove":
        del arrays[key]
        what += f"key {key} removed"
    elif op == "dtype":
        dt = pick(rng, ("f8", "f4", "i2", "u2", "i8", "bool", "c16", "U5", "S3", "V4", "M8[s]"))
        try:
            arrays[key] = np.asarray(a).astype(dt)
        except (TypeError, ValueError):
            arrays[key] = np.zeros(np.shape(a), dt)
        what += f"{key} as {dt}"
    elif op == "shape":
        a = np.asarray(a)
        choice = pick(rng, ("extra", "drop", "empty", "transpose", "scalar", "one", "long"))
        if choice == "extra":
            arrays[key] = a[..., None]
        elif choice == "drop" and a.ndim:
            arrays[key] = a[0]
        elif choice == "empty":
            arrays[key] = a[:0] if a.ndim else np.zeros(0, a.dtype)
        elif choice == "transpose" and a.ndim >= 2:
            arrays[key] = np.ascontiguousarray(np.swapaxes(a, 0, -1))
        elif choice == "one":
            arrays[key] = a[:1] if a.ndim else a
        elif choice == "long" and a.ndim:
            arrays[key] = np.concatenate([a, a])
        else:
            arrays[key] = np.zeros((), a.dtype)
        what += f"{key} shape {a.shape} -> {np.shape(arrays[key])} ({choice})"
    elif op == "nonfinite":
        key = pick(rng, [n for n in ("spacing_mm", "origin_mm", "timestamps_s", "tip_mm",
                                     "direction", "probe_pose", "entry_mm", "contrast_ratio",
                                     "tip_3d_mm", "centerline_mm") if n in arrays])
        a = np.array(arrays[key], float)
        v = pick(rng, (np.nan, np.inf, -np.inf, 1e308, -1e308, 1e-320))
        flat = a.reshape(-1)
        if flat.size:
            flat[int(rng.integers(flat.size))] = v
        arrays[key] = a
        what += f"one {key} value -> {v}"
    elif op == "value":
        key = pick(rng, ("spacing_mm", "timestamps_s", "dynamic_range_db", "origin_mm",
                         "visible"))
        a = np.array(arrays[key])
        choice = pick(rng, ("zero", "negative", "huge", "tiny", "reverse", "same"))
        if key == "visible":
            arrays[key] = np.zeros(a.shape, bool) if choice != "same" else ~a
        elif choice == "zero":
            arrays[key] = a * 0
        elif choice == "negative":
            arrays[key] = -np.abs(a) - 1
        elif choice == "huge":
            arrays[key] = a * 1e12 + 1e12
        elif choice == "tiny":
            arrays[key] = a * 1e-9
        elif choice == "reverse":
            arrays[key] = a[::-1].copy() if a.ndim else a
        else:
            arrays[key] = np.full(a.shape, a.reshape(-1)[0] if a.size else 0, a.dtype)
        what += f"{key} {choice}"
    elif op == "meta":
        meta = json.loads(str(arrays["meta"][()]))
        choice = pick(rng, ("notjson", "list", "deep", "speed", "depth", "draw", "params",
                            "huge", "nan", "drop"))
        if choice == "notjson":
            text = "{not json"
        elif choice == "list":
            text = "[1, 2]"
        elif choice == "deep":
            text = '{"params": ' + _deep_json(int(pick(rng, (50, 2000, 100000)))) + "}"
        elif choice in ("speed", "depth"):
            sec = pick(rng, ("params", "draw"))
            name = "speed_mm_s" if choice == "speed" else "rotation_depth_mm"
            meta.setdefault(sec, {})[name] = pick(rng, ("fast", None, -1, 1e300, [1], True,
                                                        {"a": 1}))
            text = json.dumps(meta)
            if rng.random() < 0.3:
                text = text.replace('"' + name + '": null', '"' + name + '": NaN')
        elif choice in ("draw", "params"):
            meta[choice] = pick(rng, (5, "x", [1, 2], None))
            text = json.dumps(meta)
        elif choice == "huge":
            meta["blob"] = "x" * 3_000_000
            text = json.dumps(meta)
        elif choice == "nan":
            text = json.dumps(meta).replace("0.1", "NaN", 1).replace("20.0", "Infinity", 1)
        else:
            meta.pop(pick(rng, sorted(meta) or ["x"]), None)
            text = json.dumps(meta)
        arrays["meta"] = np.array(text)
        what += f"meta {choice}"
    elif op == "forge":
        key = pick(rng, ("images", "spacing_mm", "timestamps_s", "tip_mm"))
        choice = pick(rng, ("huge", "huge_fortran", "descr", "short", "badpy", "object"))
        if choice == "huge":
            arrays[key] = _npy_header((10**6, 10**6, 1000)) + bytes(64)
        elif choice == "huge_fortran":
            arrays[key] = _npy_header((T, 2**40, 2**20)).replace(b"False", b"True") + bytes(64)
        elif choice == "descr":
            arrays[key] = _npy_header(np.shape(arrays[key]), pick(rng, ("<f16", "|O", "<x8",
                                                                         "bogus", "<U99999999")))
        elif choice == "short":
            arrays[key] = _npy_header((T, 10, 10)) + bytes(7)
        elif choice == "badpy":
            arrays[key] = b"\x93NUMPY\x01\x00\x20\x00{'descr': __import__('os') }     \n"
        else:
            arrays[key] = b"\x93NUMPY\x01\x00" + b"\xff\xff" + b"{" * 40
        what += f"{key} array header forged ({choice})"
    elif op == "labels":
        choice = pick(rng, ("pose_singular", "pose_huge", "pose_scaled", "dir_zero",
                            "dir_huge", "tip_far", "entry_nan", "dir_partial", "no_visible"))
        k0 = int(rng.integers(T))
        if choice.startswith("pose") and "probe_pose" in arrays:
            pose = np.array(arrays["probe_pose"], float)
            pose[k0] = {"pose_singular": np.zeros((4, 4)), "pose_huge": np.eye(4) * 1e300,
                        "pose_scaled": np.diag([1e6, 1e6, 1e6, 1.0])}[choice]
            arrays["probe_pose"] = pose
        elif choice.startswith("dir"):
            dr = np.array(arrays["direction"], float)
            dr[k0] = {"dir_zero": 0.0, "dir_huge": 1e300}.get(choice, dr[k0])
            if choice == "dir_partial":
                dr[k0, 0] = np.nan
            arrays["direction"] = dr
        elif choice == "tip_far":
            tip = np.array(arrays["tip_mm"], float)
            tip[k0] = 1e300
            arrays["tip_mm"] = tip
        elif choice == "entry_nan" and "entry_mm" in arrays:
            e = np.array(arrays["entry_mm"], float)
            e[k0] = np.nan
            arrays["entry_mm"] = e
        elif choice == "no_visible":
            arrays.pop("visible", None)
        what += f"labels {choice} (frame {k0})"
    elif op == "scalar":
        key = pick(rng, ("modality", "dynamic_range_db"))
        arrays[key] = np.array(pick(rng, ("volume", "axial", "", "inplane\0", "ünïcode", "nan",
                                          "0", "-5", "1e400")))
        what += f"{key} = {arrays[key]!r}"
    else:
        im = np.array(arrays["images"])
        choice = pick(rng, ("black", "grey", "white", "one_frame", "tiny", "thin", "noise",
                            "many"))
        if choice == "black":
            im[:] = 0
        elif choice == "grey":
            im[:] = 128
        elif choice == "white":
            im[:] = 255
        elif choice == "noise":
            im = rng.integers(0, 256, im.shape, dtype=np.uint8)
        elif choice == "one_frame":
            im[1:] = 0
        elif choice == "tiny":
            im = im[(slice(None),) + (slice(0, 2),) * nd]
            arrays = {n: v for n, v in arrays.items() if n in ("images", "spacing_mm",
                                                               "origin_mm", "modality",
                                                               "timestamps_s",
                                                               "dynamic_range_db", "meta")}
        elif choice == "thin":
            im = np.ascontiguousarray(im[(slice(None), slice(None)) + (slice(0, 2),) *
                                         (nd - 1)])
        else:
            reps = int(pick(rng, (10, 40)))
            im = np.concatenate([im] * reps)
            arrays["timestamps_s"] = np.arange(len(im)) * 0.05
            arrays = {n: v for n, v in arrays.items() if n in ("images", "spacing_mm",
                                                               "origin_mm", "modality",
                                                               "timestamps_s",
                                                               "dynamic_range_db", "meta")}
        arrays["images"] = im
        what += f"images {choice}"
    return _case("npz-arrays", what, _track(inp, rng), {inp: _npz(arrays)})


# PLUS header edits: field -> values (a callable edits the value it finds)
def _plus_edit(lines, rng, T: int, volume: bool) -> tuple[list, str]:
    field_name = pick(rng, (
        "DimSize", "DimSize", "ElementSpacing", "ElementSpacing", "ElementType",
        "CompressedDataSize", "CompressedData", "HeaderSize", "ElementDataFile", "NDims",
        "Offset", "Kinds", "ElementNumberOfChannels", "ByteOrder", "BinaryData", "ObjectType",
        "UltrasoundImageOrientation", "UltrasoundImageType", "TransformMatrix",
        "NeedlenetSequence", "Timestamp", "Timestamp", "ImageStatus", "Transform",
        "TransformStatus", "Visible", "extra", "remove", "duplicate"))
    f = field_name
    if f in ("DimSize", "ElementSpacing", "Offset", "TransformMatrix"):
        old = get_field(lines, f) or "1 1 1"
        new = edit_numbers(old, rng)
        return set_field(lines, f, new), f"{f} = {new!r} (was {old!r})"
    if f == "ElementType":
        v = pick(rng, ("MET_FLOAT", "MET_DOUBLE", "MET_SHORT", "MET_USHORT", "MET_CHAR",
                       "MET_INT", "MET_ULONG_LONG", "MET_UCHAR_ARRAY", "MET_STRING", "",
                       "MET_FLOAT MET_FLOAT", "met_uchar"))
        return set_field(lines, f, v), f"ElementType = {v!r}"
    if f == "CompressedDataSize":
        old = get_field(lines, f)
        n = int(old) if old and old.isdigit() else 1000
        v = pick(rng, ("0", "-1", "1", str(n - 1), str(n + 1), str(n * 1000), str(2**63), "x",
                       "", "1e3", None))
        if v is None:
            return remove_field(lines, f), "CompressedDataSize removed"
        return set_field(lines, f, v), f"CompressedDataSize = {v!r} (was {old!r})"
    if f == "CompressedData":
        old = get_field(lines, f)
        v = pick(rng, ("True", "False", "maybe", None))
        if v is None:
            return remove_field(lines, f), "CompressedData removed"
        return set_field(lines, f, v), f"CompressedData = {v!r} (was {old!r})"
    if f == "HeaderSize":
        v = pick(rng, ("-1", "0", "1", "100", str(2**40), "-5", "x", "99999999999999999999"))
        return set_field(lines, f, v), f"HeaderSize = {v!r}"
    if f == "ElementDataFile":
        v = pick(rng, ("LOCAL", "LIST", "missing.raw", "/dev/zero", "/dev/null", ".", "..",
                       "sub", "%03d.raw", "a b c", "/proc/self/status", "i.mhd",
                       "../../../../../../etc/hostname", "", "i.raw extra"))
        return set_field(lines, f, v), f"ElementDataFile = {v!r}"
    if f == "NDims":
        v = pick(rng, ("0", "1", "2", "3", "4", "5", "-1", "100", "x", "3.0", ""))
        return set_field(lines, f, v), f"NDims = {v!r}"
    if f == "Kinds":
        v = pick(rng, ("domain domain domain", "list domain domain", "domain list",
                       "foo bar baz", "", "domain domain domain domain list",
                       "domain domain list list"))
        return set_field(lines, f, v), f"Kinds = {v!r}"
    if f == "ElementNumberOfChannels":
        v = pick(rng, ("0", "2", "3", "4", "5", "-1", "1000", "x"))
        return set_field(lines, f, v), f"ElementNumberOfChannels = {v!r}"
    if f == "ByteOrder":
        k = pick(rng, ("BinaryDataByteOrderMSB", "ElementByteOrderMSB"))
        v = pick(rng, ("True", "maybe", ""))
        return set_field(lines, k, v), f"{k} = {v!r}"
    if f == "BinaryData":
        v = pick(rng, ("False", "x"))
        return set_field(lines, f, v), f"BinaryData = {v!r}"
    if f == "ObjectType":
        v = pick(rng, ("Mesh", "", "image"))
        return set_field(lines, f, v), f"ObjectType = {v!r}"
    if f == "UltrasoundImageOrientation":
        v = pick(rng, ("UN", "MFD", "XX", "", "MFA", "UF", "MN", "UNDA", "mf"))
        return set_field(lines, f, v), f"{f} = {v!r}"
    if f == "UltrasoundImageType":
        v = pick(rng, ("RF", "COLOR", "", "brightness"))
        return set_field(lines, f, v), f"{f} = {v!r}"
    if f == "NeedlenetSequence":
        old = get_field(lines, f)
        try:
            d = json.loads(old) if old else {}
        except json.JSONDecodeError:
            d = {}
        choice = pick(rng, ("notjson", "empty", "modality", "dr", "meta", "deep", "speed"))
        if choice == "notjson":
            v = "{nope"
        elif choice == "empty":
            v = "{}"
        elif choice == "modality":
            d["modality"] = pick(rng, ("volume", "axial", "bogus", 5, None))
            v = json.dumps(d)
        elif choice == "dr":
            d["dynamic_range_db"] = pick(rng, ("x", 0, -1, 1e308, None, [1]))
            v = json.dumps(d)
        elif choice == "meta":
            d["meta"] = pick(rng, ([], "x", None, {"params": 5}))
            v = json.dumps(d)
        elif choice == "speed":
            d.setdefault("meta", {})["params"] = {"speed_mm_s": pick(rng, ("x", -5, 1e300))}
            v = json.dumps(d)
        else:
            v = '{"modality": "inplane", "dynamic_range_db": 60, "meta": ' + \
                _deep_json(int(pick(rng, (3000, 100000)))) + "}"
        return set_field(lines, f, v), f"NeedlenetSequence: {choice}"
    if f in ("Timestamp", "ImageStatus", "Transform", "TransformStatus", "Visible"):
        k = int(rng.integers(T))
        if f == "Timestamp":
            key = f"Seq_Frame{k:04d}_Timestamp"
            choice = pick(rng, ("nan", "inf", "-1", "1e300", "x", "", "remove", "same",
                                "spread", "reverse", "all_same", "jump"))
            if choice == "remove":
                return remove_field(lines, key), f"{key} removed"
            if choice in ("spread", "reverse", "all_same", "jump"):
                out = [list(x) for x in lines]
                n = 0
                for x in out:
                    m = re.match(r"Seq_Frame(\d+)_Timestamp$", x[0])
                    if m:
                        i = int(m.group(1))
                        x[1] = {"spread": repr(i * 1e6), "reverse": repr(float(T - i)),
                                "all_same": "1.0", "jump": repr(i * 0.05 if i < T - 1
                                                                 else 1e7)}[choice]
                        n += 1
                return out, f"timestamps {choice} ({n} frames)"
            if choice == "same":
                prev = get_field(lines, f"Seq_Frame{max(k - 1, 0):04d}_Timestamp") or "0"
                return set_field(lines, key, prev), f"{key} = previous frame's"
            return set_field(lines, key, choice), f"{key} = {choice!r}"
        if f == "ImageStatus":
            choice = pick(rng, ("INVALID", "BAD", "", "all_invalid"))
            if choice == "all_invalid":
                out = [[x[0], "INVALID"] if x[0].endswith("_ImageStatus") else list(x)
                       for x in lines]
                return out, "every ImageStatus = INVALID"
            return set_field(lines, f"Seq_Frame{k:04d}_ImageStatus", choice), \
                f"frame {k} ImageStatus = {choice!r}"
        names = sorted({m.group(1) for x in lines
                        if (m := re.match(r"Seq_Frame\d+_(\w+)Transform$", x[0]))})
        name = pick(rng, names or ["ProbeToReference"])
        if f == "TransformStatus":
            v = pick(rng, ("INVALID", "x", ""))
            key = f"Seq_Frame{k:04d}_{name}TransformStatus"
            return set_field(lines, key, v), f"{key} = {v!r}"
        if f == "Visible":
            v = pick(rng, ("maybe", "", "TRUE", "0"))
            key = f"Seq_Frame{k:04d}_NeedleTipVisible"
            return set_field(lines, key, v), f"{key} = {v!r}"
        key = f"Seq_Frame{k:04d}_{name}Transform"
        choice = pick(rng, ("nan", "fifteen", "text", "singular", "huge", "tiny", "all_singular",
                            "all_huge", "shear"))
        eye = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
        v = {"nan": " ".join(["nan"] * 16), "fifteen": " ".join(["1"] * 15), "text": "x",
             "singular": " ".join(["0"] * 16), "huge": " ".join(str(1e300 * e) for e in eye),
             "tiny": " ".join(str(1e-300 * e) for e in eye),
             "shear": "1 1e12 0 0 0 1 0 0 0 0 1 0 0 0 0 1"}.get(choice)
        if choice in ("all_singular", "all_huge"):
            mat = " ".join(["0"] * 16) if choice == "all_singular" else \
                " ".join(str(1e300 * e) for e in eye)
            out = [[x[0], mat] if x[0].endswith(f"_{name}Transform") else list(x)
                   for x in lines]
            return out, f"every {name}Transform {choice[4:]}"
        return set_field(lines, key, v), f"{key} {choice}"
    if f == "extra":
        kv = pick(rng, (("Seq_Frame9999_Timestamp", "0"),
                        ("Seq_Frame99999999999999999999_Foo", "1"), ("Seq_Frame-1_Foo", "1"),
                        ("NoEquals", None), ("=", "5"), ("Binary\x01Key", "1"),
                        ("LongField", "x" * 5_000_000), ("Seq_Frame0000_ImageStatus", "OK")))
        out = [list(x) for x in lines]
        out.insert(int(rng.integers(1, len(out))), list(kv))
        return out, f"extra line {kv[0][:40]!r}"
    if f == "remove":
        k = pick(rng, ("NDims", "DimSize", "ElementType", "ElementSpacing", "ElementDataFile",
                       "Offset", "ObjectType", "Kinds", "timestamps"))
        if k == "timestamps":
            return [list(x) for x in lines if not x[0].endswith("_Timestamp")], \
                "every timestamp removed"
        return remove_field(lines, k), f"{k} removed"
    k = pick(rng, ("DimSize", "NDims", "ElementSpacing"))
    out = [list(x) for x in lines]
    i = next(j for j, x in enumerate(out) if x[0] == k)
    out.insert(i, list(out[i]))
    return out, f"{k} twice"


def fam_plus_header(rng, base: Base) -> dict:
    inp = pick(rng, PLUS_INPUTS)
    files = base.input_files(inp)
    head, body = split_mha(files[inp])
    T = int(head[[x[0] for x in head].index("DimSize")][1].split()[-1])
    volume = inp.startswith("v")
    whats = []
    for _ in range(int(pick(rng, (1, 1, 1, 2, 3)))):
        head, w = _plus_edit(head, rng, T, volume)
        whats.append(w)
    if inp.endswith(".mhd") and rng.random() < 0.1:
        files[inp] = join_mha(set_field(head, "ElementDataFile", "LOCAL"), files[
            inp.replace(".mhd", ".raw" if inp == "i.mhd" else ".zraw")])
        whats.append("pixels inside the .mhd")
    else:
        files[inp] = join_mha(head, body)
    if "sub" in " ".join(whats):
        files["sub/"] = b""
    extra = ["--realtime"] if rng.random() < 0.15 else []  # paced at the file's times
    return _case("plus-header", f"{inp}: " + "; ".join(whats) + (" --realtime" if extra else ""),
                 _track(inp, rng, extra), files)


def fam_plus_bytes(rng, base: Base) -> dict:
    inp = pick(rng, PLUS_INPUTS)
    files = base.input_files(inp)
    target = pick(rng, sorted(files))
    data = files[target]
    if target.endswith(".mha"):
        j = data.index(b"\n", data.index(b"ElementDataFile")) + 1
        lo, hi, where = (0, j, "header") if rng.random() < 0.4 else (j, len(data), "pixels")
    else:
        lo, hi, where = 0, len(data), "file"
    files[target], what = mutate_bytes(data, rng, lo, hi)
    return _case("plus-bytes", f"{target}: {what} ({where})", _track(inp, rng), files)


def fam_pixels(rng, base: Base) -> dict:
    """Float recordings whose pixels are NaN, inf, huge, constant; empty or one-grey frames."""
    fmt = pick(rng, ("plus", "plus", "nrrd"))
    s = base.seqs["i"]
    a = s.images.astype(np.float32) * 0.01 + 3.0
    choice = pick(rng, ("nan1", "nanframe", "allnan", "inf1", "-inf", "huge1", "hugeframe",
                        "const", "black", "neg", "denormal", "mixed", "max"))
    flat = a.reshape(-1)
    n = flat.size
    if choice == "nan1":
        flat[rng.integers(n, size=int(rng.integers(1, 50)))] = np.nan
    elif choice == "nanframe":
        a[int(rng.integers(len(a)))] = np.nan
    elif choice == "allnan":
        a[:] = np.nan
    elif choice == "inf1":
        flat[rng.integers(n, size=5)] = np.inf
    elif choice == "-inf":
        flat[rng.integers(n, size=5)] = -np.inf
    elif choice == "huge1":
        flat[rng.integers(n, size=3)] = 1e6
    elif choice == "hugeframe":
        a[int(rng.integers(len(a)))] = 3e38
    elif choice == "const":
        a[:] = 7.5
    elif choice == "black":
        a[:] = 0.0
    elif choice == "neg":
        a = -a
    elif choice == "denormal":
        a = a * 1e-44
    elif choice == "mixed":
        a[0] = np.nan
        a[1] = np.inf
        a[2] = 0
    else:
        a[:] = np.finfo(np.float32).max
    if fmt == "plus":
        head, _ = split_mha(base.files["if.seq.mha"])
        dt = pick(rng, ("MET_FLOAT", "MET_DOUBLE"))
        body = a.astype("<f4" if dt == "MET_FLOAT" else "<f8").tobytes()
        name = "p.seq.mha"
        files = {name: join_mha(set_field(head, "ElementType", dt), body)}
    else:
        name = "p.nrrd"
        files = {name: _nrrd_2d(a, s.spacing_mm, s.timestamps_s, dtype="float")}
    return _case("pixels", f"{name} float pixels: {choice}", _track_any(name, rng), files)
