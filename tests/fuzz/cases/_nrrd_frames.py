"""Case families: NRRD header fields and bytes, PNG folders with sidecars, videos."""

from __future__ import annotations

import json
import re
import struct
import zlib

import numpy as np

from ._base import (
    INPUTS,
    NRRD_INPUTS,
    SIDECAR,
    Base,
    _case,
    _deep_json,
    _png,
    _track,
    edit_numbers,
    join_nrrd,
    mutate_bytes,
    nrrd_set,
    pick,
    split_nrrd,
)


def _nrrd_edit(lines, rng, nd_frames: int) -> tuple[list[str], str]:
    f = pick(rng, ("type", "dimension", "sizes", "sizes", "encoding", "endian", "data file",
                   "space directions", "space directions", "spacings", "kinds", "kinds",
                   "space origin", "line skip", "byte skip", "index values", "space",
                   "space dimension", "magic", "remove", "thicknesses", "axis mins"))
    if f == "type":
        v = pick(rng, ("uchar", "float", "double", "int16", "uint64", "bogus", "", "block",
                       "signed char"))
        return nrrd_set(lines, "type", v), f"type: {v!r}"
    if f == "dimension":
        v = pick(rng, ("0", "1", "2", "4", "5", "17", "-1", "x", "1000"))
        return nrrd_set(lines, "dimension", v), f"dimension: {v!r}"
    if f == "sizes":
        old = next(ln.split(": ", 1)[1] for ln in lines if ln.startswith("sizes:"))
        v = edit_numbers(old, rng)
        return nrrd_set(lines, "sizes", v), f"sizes: {v!r} (was {old!r})"
    if f == "encoding":
        v = pick(rng, ("raw", "gzip", "gz", "bzip2", "ascii", "text", "hex", "bogus", ""))
        return nrrd_set(lines, "encoding", v), f"encoding: {v!r}"
    if f == "endian":
        v = pick(rng, ("big", "middle", ""))
        return nrrd_set(lines, "endian", v), f"endian: {v!r}"
    if f == "data file":
        v = pick(rng, ("missing.raw", "/dev/zero", "/dev/urandom", ".", "LIST", "i.nhdr",
                       "../x.raw", "%d.raw 0 4 1", "i_data.raw", "/proc/self/status", "sub",
                       "LIST 2"))
        return nrrd_set(lines, "data file", v), f"data file: {v!r}"
    if f == "space directions":
        old = next((ln.split(": ", 1)[1] for ln in lines
                    if ln.startswith("space directions:")), "")
        parts = old.split()
        choice = pick(rng, ("allnone", "nan", "zero", "short", "bad", "huge", "tiny", "remove",
                            "extra"))
        if choice == "allnone":
            parts = ["none"] * len(parts)
        elif choice == "remove":
            return nrrd_set(lines, "space directions", None), "space directions removed"
        elif choice == "short" and parts:
            parts = parts[:-1]
        elif choice == "extra":
            parts = parts + parts[:1]
        elif parts:
            k = int(rng.integers(len(parts)))
            n = parts[k].count(",") + 1 if parts[k] != "none" else 2
            val = {"nan": "nan", "zero": "0", "huge": "1e300", "tiny": "1e-300"}.get(choice)
            parts[k] = "(1,2" if choice == "bad" else "(" + ",".join([val] * n) + ")"
        v = " ".join(parts)
        return nrrd_set(lines, "space directions", v), f"space directions: {v!r}"
    if f == "spacings":
        v = pick(rng, ("nan nan nan", "0 0.1 nan", "-1 -1 nan", "1e9 1e9 nan", "0.1 0.1",
                       "x y z"))
        out = nrrd_set(lines, "space directions", None) if rng.random() < 0.7 else lines
        out = nrrd_set(out, "space dimension", None)
        out = nrrd_set(out, "space origin", None)
        return nrrd_set(out, "spacings", v), f"spacings: {v!r} (space directions removed)"
    if f == "kinds":
        old = next((ln.split(": ", 1)[1] for ln in lines if ln.startswith("kinds:")), "")
        parts = old.split()
        choice = pick(rng, ("list", "RGB-color", "3-color", "vector", "bogus", "drop", "time",
                            "remove", "space"))
        if choice == "remove":
            return nrrd_set(lines, "kinds", None), "kinds removed"
        if choice == "drop" and parts:
            parts = parts[1:]
        elif parts:
            parts[int(rng.integers(len(parts)))] = choice
        v = " ".join(parts)
        return nrrd_set(lines, "kinds", v), f"kinds: {v!r}"
    if f == "space origin":
        v = pick(rng, ("(nan,nan)", "(1,2,3,4)", "(1e308,1e308)", "x", "(0,0,0)"))
        return nrrd_set(lines, "space origin", v), f"space origin: {v!r}"
    if f == "line skip":
        v = pick(rng, ("1", "100", "1000000000", "-1", "x"))
        return nrrd_set(lines, "line skip", v), f"line skip: {v!r}"
    if f == "byte skip":
        v = pick(rng, ("-1", "1", "100", "100000000", "-5", "x"))
        return nrrd_set(lines, "byte skip", v), f"byte skip: {v!r}"
    if f == "index values":
        key = next((re.split(":=", ln)[0] for ln in lines if ":=" in ln), "axis 2 index values")
        v = pick(rng, ("nan nan nan nan nan", "0 0.05", "4 3 2 1 0", "x", "",
                       "0 1e300 2e300 3e300 4e300", "0 0 0 0 0", "0 1e-9 2e-9 3e-9 4e-9",
                       "0 " * nd_frames + "5"))
        return nrrd_set(lines, key, v, custom=True), f"{key}: {v!r}"
    if f == "space":
        v = pick(rng, ("bogus", "left-posterior-superior", "3D-right-handed-time"))
        return nrrd_set(lines, "space", v), f"space: {v!r}"
    if f == "space dimension":
        v = pick(rng, ("1", "3", "5", "0", "x"))
        return nrrd_set(lines, "space dimension", v), f"space dimension: {v!r}"
    if f == "thicknesses":
        return nrrd_set(lines, "thicknesses", "nan x 1"), "thicknesses: 'nan x 1'"
    if f == "axis mins":
        v = pick(rng, ("nan nan nan", "0 0", "1e308 1e308 0"))
        return nrrd_set(lines, "axis mins", v), f"axis mins: {v!r}"
    if f == "magic":
        v = pick(rng, ("NRRD0009", "NRRD", "NRRD0001", "nrrd0004", "P5"))
        return [v] + lines[1:], f"magic line {v!r}"
    k = pick(rng, ("type", "sizes", "dimension", "encoding", "kinds", "endian"))
    return nrrd_set(lines, k, None), f"{k} removed"


def fam_nrrd_header(rng, base: Base) -> dict:
    inp = pick(rng, NRRD_INPUTS)
    files = base.input_files(inp)
    if inp.endswith(".nhdr"):
        lines, body = files[inp].decode().splitlines(), b""
    else:
        lines, body = split_nrrd(files[inp])
    n_frames = 3 if inp.startswith("v") else 5
    whats = []
    for _ in range(int(pick(rng, (1, 1, 2)))):
        lines, w = _nrrd_edit(lines, rng, n_frames)
        whats.append(w)
    if inp.endswith(".nhdr"):
        files[inp] = ("\n".join(lines) + "\n").encode()
    else:
        files[inp] = join_nrrd(lines, body)
    if any("'sub'" in w for w in whats):
        files["sub/"] = b""
    return _case("nrrd-header", f"{inp}: " + "; ".join(whats), _track(inp, rng), files)


def fam_nrrd_bytes(rng, base: Base) -> dict:
    inp = pick(rng, NRRD_INPUTS)
    files = base.input_files(inp)
    target = pick(rng, sorted(files))
    data = files[target]
    j = data.find(b"\n\n")
    if target.endswith(("nrrd",)) and j > 0 and rng.random() < 0.5:
        lo, hi, where = 0, j + 2, "header"
    else:
        lo, hi, where = (j + 2 if j > 0 else 0), len(data), "data"
    files[target], what = mutate_bytes(data, rng, lo, hi)
    return _case("nrrd-bytes", f"{target}: {what} ({where})", _track(inp, rng), files)


def _png_chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(payload)) + kind + payload + \
        struct.pack(">I", zlib.crc32(kind + payload) & 0xFFFFFFFF)


def png_claiming(width: int, height: int, depth: int = 8, color: int = 0) -> bytes:
    """A PNG whose header claims ``width`` x ``height`` pixels with a few rows of data: a
    reader that trusts the header allocates the whole image first."""
    ihdr = struct.pack(">IIBBBBB", width, height, depth, color, 0, 0, 0)
    row = b"\0" + bytes(min(width, 1 << 16))
    return b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + \
        _png_chunk(b"IDAT", zlib.compress(row * 4)) + _png_chunk(b"IEND", b"")


def _sidecar_edit(rng) -> tuple[object, str]:
    key = pick(rng, ("spacing_mm", "fps", "timestamps_s", "crop", "modality", "origin_mm",
                     "dynamic_range_db", "unknown", "whole"))
    if key == "whole":
        v = pick(rng, ("{not json", "[]", "null", "5", '"x"', "", "\xff\xfe", '{"fps": NaN}',
                       '{"spacing_mm": Infinity, "fps": 20}', _deep_json(100000)))
        return v, f"sidecar text {v[:30]!r}"
    d = dict(SIDECAR)
    if key == "unknown":
        d["spacing"] = 0.1
        return d, "sidecar key 'spacing' (misspelt)"
    vals = {
        "spacing_mm": (0, -1, 1e-9, 1e9, [0.1, 0.1, 0.1], "x", None, [], [[0.1]], True,
                       [0.1, -0.1], 1e308),
        "fps": (0, -1, 1e-300, 1e300, "x", None, [20, 30], True, 0.01),
        "timestamps_s": ([0, 0.05], [4, 3, 2, 1, 0], ["a"] * 5, [0, 1, 2, 3, None],
                         [[0, 1], [2, 3]], 5, [0, 1e300, 2e300, 3e300, 4e300], [0] * 5,
                         [0, 1e-9, 2e-9, 3e-9, 4e-9], list(range(1000)), {}),
        "crop": ([0, 0, 10], [-5, 0, 50, 50], [0, 0, 100000, 100000], [0, 0, 0, 0],
                 [1.5, 2.5, 50, 50], ["a", 0, 1, 1], [0, 0, 1e30, 50], [10, 10, 50, 50],
                 [0, 0, 2**70, 5], None),
        "modality": ("volume", "bogus", 5, None, ["inplane"], "axial"),
        "origin_mm": ([1e308, 1e308], [0], "x", [0, 0, 0], [1e-300, 5]),
        "dynamic_range_db": (0, -5, 1e308, "x", None, [60]),
    }[key]
    v = vals[int(rng.integers(len(vals)))]
    d[key] = v
    if key == "timestamps_s":
        d.pop("fps")
    return d, f"sidecar {key} = {json.dumps(v)[:40]}"


def fam_frames(rng, base: Base) -> dict:
    """A folder of PNG frames: damaged, odd-sized, 16-bit, colour, bogus header sizes, empty;
    and its sidecar JSON."""
    import cv2

    inp = pick(rng, ("frames", "bare"))
    files = base.input_files(inp)
    pngs = sorted(k for k in files if k.endswith(".png"))
    k = pick(rng, pngs)
    s = base.seqs["i"]
    choice = pick(rng, ("bytes", "bytes", "size", "16bit", "color", "rgba", "claims", "empty",
                        "text", "none", "tiny", "sidecar", "sidecar", "sidecar", "jpeg",
                        "extra", "subdir", "one"))
    what = f"{inp}: "
    if choice == "bytes":
        files[k], w = mutate_bytes(files[k], rng)
        what += f"{k}: {w}"
    elif choice == "size":
        files[k] = _png(s.images[0][:50, :60])
        what += f"{k} is 60x50"
    elif choice == "16bit":
        files[k] = _png(s.images[0].astype(np.uint16) * 200)
        what += f"{k} 16-bit"
    elif choice == "color":
        files[k] = _png(cv2.cvtColor(s.images[0], cv2.COLOR_GRAY2BGR))
        what += f"{k} colour"
    elif choice == "rgba":
        files = {n: (_png(cv2.cvtColor(s.images[0], cv2.COLOR_GRAY2BGRA))
                     if n.endswith(".png") else v) for n, v in files.items()}
        what += "every frame RGBA"
    elif choice == "claims":
        w, h = pick(rng, ((50000, 50000), (2**31 - 1, 2), (30000, 30000), (65535, 65535),
                          (1, 2**31 - 1)))
        depth, color = pick(rng, ((8, 0), (16, 2), (8, 6)))
        files[k] = png_claiming(w, h, depth, color)
        what += f"{k} claims {w}x{h} (depth {depth}, colour type {color})"
    elif choice == "empty":
        files[k] = b""
        what += f"{k} empty"
    elif choice == "text":
        files[k] = b"this is not a png\n"
        what += f"{k} is text"
    elif choice == "none":
        files = {n: v for n, v in files.items() if not n.endswith(".png")}
        files[f"{inp}/"] = b""
        what += "no image files"
    elif choice == "tiny":
        files = {n: (_png(np.full((1, 1), 9, np.uint8)) if n.endswith(".png") else v)
                 for n, v in files.items()}
        what += "every frame 1x1"
    elif choice == "one":
        files = {n: v for n, v in files.items() if not n.endswith(".png") or n == pngs[0]}
        what += "a single frame"
    elif choice == "jpeg":
        ok, buf = cv2.imencode(".jpg", s.images[0])
        data = bytearray(buf.tobytes())
        sof = data.find(b"\xff\xc0")
        if sof > 0 and rng.random() < 0.7:
            data[sof + 5:sof + 9] = struct.pack(">HH", 65500, 65500)
            what += "frame.jpg with a SOF claiming 65500x65500"
        else:
            what += "frame.jpg"
        files[f"{inp}/{k.split('/')[1][:-4]}b.jpg"] = bytes(data)
    elif choice == "extra":
        files[f"{inp}/notes.txt"] = b"hello"
        files[f"{inp}/zz.PNG"] = files[k]
        what += "extra files (.txt, .PNG)"
    elif choice == "subdir":
        files[f"{inp}/999.png/"] = b""
        what += "a folder named 999.png"
    else:
        sc, w = _sidecar_edit(rng)
        files[f"{inp}/frames.json"] = (sc if isinstance(sc, str) else json.dumps(sc)).encode(
            "utf-8", "surrogatepass")
        what += w
    extra = INPUTS[inp][2]
    if inp == "bare" and choice == "sidecar":
        extra = ()
    argv = ["track", "{d}/" + inp, "--quiet", "--json", "{d}/out.json", *extra]
    if rng.random() < 0.5:
        argv += ["--features", "classical"]
    return _case("frames", what, argv, files)


def fam_video(rng, base: Base) -> dict:
    inp = pick(rng, ("clip.avi", "bare.avi"))
    files = base.input_files(inp)
    data = files[inp]
    choice = pick(rng, ("bytes", "bytes", "bytes", "cut", "empty", "png", "text", "sof",
                        "header", "sidecar", "sidecar", "sidecar", "rename"))
    what = f"{inp}: "
    name = inp
    if choice == "bytes":
        files[inp], w = mutate_bytes(data, rng)
        what += w
    elif choice == "cut":
        at = int(rng.integers(len(data)))
        files[inp] = data[:at]
        what += f"cut at {at} of {len(data)}"
    elif choice == "empty":
        files[inp] = b""
        what += "empty"
    elif choice == "png":
        files[inp] = base.files["frames/000.png"]
        what += "a PNG named .avi"
    elif choice == "text":
        files[inp] = b"RIFF\x10\x00\x00\x00AVI LIST" + b"x" * 100
        what += "an AVI header and nothing else"
    elif choice == "sof":
        b = bytearray(data)
        n = 0
        i = b.find(b"\xff\xc0")
        while i > 0 and n < 5:
            b[i + 5:i + 9] = struct.pack(">HH", *pick(rng, ((65500, 65500), (0, 0), (1, 60000))))
            i = b.find(b"\xff\xc0", i + 1)
            n += 1
        files[inp] = bytes(b)
        what += f"JPEG frame sizes edited in {n} frames"
    elif choice == "header":
        b = bytearray(data)
        i = b.find(b"avih")
        field_no = int(rng.integers(0, 10))
        val = pick(rng, (0, 0xFFFFFFFF, 0x7FFFFFFF, 100000))
        if i > 0:
            b[i + 8 + 4 * field_no:i + 12 + 4 * field_no] = struct.pack("<I", val)
        j = b.find(b"strf")
        if j > 0 and rng.random() < 0.5:
            b[j + 12:j + 20] = struct.pack("<ii", val & 0x7FFFFFFF, -(val & 0x7FFFFFFF))
        files[inp] = bytes(b)
        what += f"avih field {field_no} = {val}"
    elif choice == "rename":
        name = pick(rng, ("clip.mp4", "clip.mkv", "clip.mov"))
        files = {name: data, name[:-4] + ".json": json.dumps(SIDECAR).encode()}
        what += f"the MJPG AVI named {name}"
    else:
        sc, w = _sidecar_edit(rng)
        files["clip.json"] = (sc if isinstance(sc, str) else json.dumps(sc)).encode(
            "utf-8", "surrogatepass")
        if inp == "bare.avi":
            files["bare.json"] = files.pop("clip.json")
        what += w
    extra = INPUTS[inp][2] if name == inp and choice != "sidecar" else ()
    argv = ["track", "{d}/" + name, "--quiet", "--json", "{d}/out.json", *extra]
    if rng.random() < 0.5:
        argv += ["--features", "classical"]
    return _case("video", what, argv, files)
