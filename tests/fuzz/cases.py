"""A seeded generator of bad inputs for ``needlenet track`` and ``needlenet synth`` (issue 21).

**Valid inputs first.** :class:`Base` makes, once per run, small valid recordings of each kind
the readers take: ``synth.generate`` sequences (in-plane 5 x 100 x 120 px, axial 5 x 80 x 80,
volume 3 x 32^3: every case then runs in well under a second) written as ``.npz``, PLUS
``.seq.mha`` compressed and not, ``.mhd`` + ``.raw`` / ``.zraw``, float PLUS pixels, NRRD with
the data attached (raw and gzip) and detached, a float NRRD, a PNG folder with and without a
sidecar JSON, an ``.avi`` with and without one, and tiny valid ONNX models (made with
``onnx.helper``, like ``tests/features/test_model_checks.py``).

**Cases.** :func:`generate_cases` yields :class:`Case` objects: an id, a family, a one-line
description of the mutation, the ``needlenet`` argv (``{d}`` stands for the case's own
directory), the files the case needs (copies of the valid inputs, some mutated) and what may
happen: by default a clean one-line error or a clean run; cases on output paths also name the
outputs that may be written (anything else that changes is damage). Case ``i`` of seed ``s``
draws from ``numpy.random.default_rng([s, i])`` and its family is fixed by ``i``
(:data:`SCHEDULE`, round robin), so the same seed gives the same cases, the first ``n`` cases
of a longer run are the ``n`` cases of a shorter one, and any 49 consecutive cases cover
every family.

**Families** (see :data:`FAMILIES`): bytes flipped or cut in every file kind; npz arrays with
keys removed, wrong dtypes and shapes, NaN / inf, forged array headers and edited meta JSON;
PLUS header fields (DimSize, ElementSpacing, ElementType, CompressedDataSize, HeaderSize,
ElementDataFile, NDims, Offset, Kinds, channels, orientation, timestamps, ImageStatus,
transforms, needlenet's own JSON field); float pixels that are NaN, inf or 1e6; NRRD fields
(type, dimension, sizes, encoding, endian, data file, space directions, spacings, kinds,
origin, skips, frame times); PNG folders and videos (damaged, odd-sized, 16-bit, colour,
empty, bogus sizes in the PNG and JPEG headers) and their sidecar JSON; models (metadata,
ranks, fixed shapes, output shapes and types, NaN / inf outputs, damaged files);
``--param`` with wrong types, huge, negative and non-finite values for the real fields of
the tracker parameter classes (read from the dataclasses, so the suite follows the code);
absurd ``--spacing --fps --crop --angle --tracker --method --seed --igtl`` options; output
paths (existing directories, the input and the files beside it, missing or unwritable
directories, existing files with and without ``--overwrite``, names too long); ``synth``
options; special files (FIFOs, devices, symlinks, folders named like files); bombs (files of
kilobytes whose headers claim, or whose compressed data inflates to, gigabytes); and
controls, valid inputs that must track.
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import re
import struct
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Case", "Base", "FAMILIES", "SCHEDULE", "generate_cases", "make_case"]

CLEAN = ("clean-error", "ok")


@dataclass
class Case:
    """One fuzz case. ``files`` maps a path relative to the case directory to its bytes (a
    path ending in ``/`` is an empty directory); ``links`` to a symlink target; ``fifos``
    are named pipes. ``outputs`` are the relative paths the command may create, and replace
    only with ``--overwrite``; every other file that existed before must be unchanged after.
    ``expect``: the outcomes that pass."""

    id: str
    family: str
    what: str
    argv: list[str]
    files: dict[str, bytes] = field(default_factory=dict)
    expect: tuple[str, ...] = CLEAN
    outputs: tuple[str, ...] = ()
    links: dict[str, str] = field(default_factory=dict)
    fifos: tuple[str, ...] = ()
    modes: dict[str, int] = field(default_factory=dict)

    def materialize(self, root: Path) -> Path:
        """Write the case's files into ``root / id`` (made afresh); return that directory."""
        d = Path(root) / self.id
        d.mkdir(parents=True)
        for rel, data in self.files.items():
            p = d / rel
            if rel.endswith("/"):
                p.mkdir(parents=True, exist_ok=True)
                continue
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        for rel in self.fifos:
            (d / rel).parent.mkdir(parents=True, exist_ok=True)
            os.mkfifo(d / rel)
        for rel, target in self.links.items():
            (d / rel).parent.mkdir(parents=True, exist_ok=True)
            os.symlink(target.format(d=d), d / rel)
        for rel, mode in self.modes.items():
            os.chmod(d / rel, mode)
        return d

    def command(self, d: Path) -> list[str]:
        """The argv with the case directory filled in."""
        return [a.replace("{d}", str(d)) for a in self.argv]


# -- the valid inputs -------------------------------------------------------------------------

SEQ_SPECS = {
    "i": ("inplane", {"seed": 1, "frames": 5, "width_mm": 12.0, "depth_mm": 10.0,
                      "start_length_mm": 6.0, "background": "homogeneous"}),
    "a": ("axial", {"seed": 1, "frames": 5, "width_mm": 12.0, "depth_mm": 12.0,
                    "spacing_mm": 0.15, "background": "homogeneous"}),
    "v": ("volume", {"seed": 1, "frames": 3, "output_size": 32, "background": "homogeneous"}),
}

# input name -> (its files, modality, options it needs); a folder's files carry its name
INPUTS: dict[str, tuple[tuple[str, ...], str, tuple[str, ...]]] = {
    "i.npz": (("i.npz",), "inplane", ()),
    "a.npz": (("a.npz",), "axial", ()),
    "v.npz": (("v.npz",), "volume", ()),
    "i.seq.mha": (("i.seq.mha",), "inplane", ()),
    "iu.seq.mha": (("iu.seq.mha",), "inplane", ()),
    "a.seq.mha": (("a.seq.mha",), "axial", ()),
    "v.seq.mha": (("v.seq.mha",), "volume", ()),
    "vu.seq.mha": (("vu.seq.mha",), "volume", ()),
    "if.seq.mha": (("if.seq.mha",), "inplane", ()),
    "i.mhd": (("i.mhd", "i.raw"), "inplane", ()),
    "iz.mhd": (("iz.mhd", "iz.zraw"), "inplane", ()),
    "i.seq.nrrd": (("i.seq.nrrd",), "inplane", ()),
    "ig.seq.nrrd": (("ig.seq.nrrd",), "inplane", ()),
    "i.nhdr": (("i.nhdr", "i_data.raw"), "inplane", ()),
    "v.seq.nrrd": (("v.seq.nrrd",), "volume", ()),
    "if.nrrd": (("if.nrrd",), "inplane", ()),
    "frames": (tuple(f"frames/{k:03d}.png" for k in range(5)) + ("frames/frames.json",),
               "inplane", ()),
    "bare": (tuple(f"bare/{k:03d}.png" for k in range(5)), "inplane",
             ("--spacing", "0.1", "--fps", "20")),
    "clip.avi": (("clip.avi", "clip.json"), "inplane", ()),
    "bare.avi": (("bare.avi",), "inplane", ("--spacing", "0.1")),
}
PLUS_INPUTS = ("i.seq.mha", "iu.seq.mha", "a.seq.mha", "v.seq.mha", "vu.seq.mha", "if.seq.mha",
               "i.mhd", "iz.mhd")
NRRD_INPUTS = ("i.seq.nrrd", "ig.seq.nrrd", "i.nhdr", "v.seq.nrrd", "if.nrrd")
NPZ_INPUTS = ("i.npz", "a.npz", "v.npz")
MODELS = {"inplane": "m.onnx", "axial": "ma.onnx", "volume": "mv.onnx"}
SIDECAR = {"spacing_mm": 0.1, "fps": 20}


def _nrrd_2d(images: np.ndarray, spacing, ts, dtype="uint8", encoding="raw") -> bytes:
    """A NRRD sequence of 2D frames as 3D Slicer writes one (list axis last, frame times in
    ``axis 2 index values``)."""
    T, H, W = images.shape
    body = np.ascontiguousarray(images).tobytes()
    if encoding == "gzip":
        import gzip

        body = gzip.compress(body, mtime=0)
    dz, dx = (float(s) for s in spacing)
    head = ["NRRD0004", f"type: {dtype}", "dimension: 3", "space dimension: 2",
            f"sizes: {W} {H} {T}", f"space directions: ({dx:g},0) (0,{dz:g}) none",
            "kinds: domain domain list", "endian: little", f"encoding: {encoding}",
            "space origin: (0,0)", "axis 2 index values:=" + " ".join(f"{t:g}" for t in ts)]
    return ("\n".join(head) + "\n\n").encode() + body


def _nrrd_3d(images: np.ndarray, spacing, ts) -> bytes:
    T, Z, Y, X = images.shape  # [depth, elevation, lateral]: file axes x, elevation, depth
    data = np.ascontiguousarray(images.transpose(0, 1, 2, 3)).tobytes()
    dz, dy, dx = (float(s) for s in spacing)
    head = ["NRRD0004", "type: uint8", "dimension: 4", "space: left-posterior-superior",
            f"sizes: {X} {Y} {Z} {T}",
            f"space directions: ({dx:g},0,0) (0,{dy:g},0) (0,0,{dz:g}) none",
            "kinds: domain domain domain list", "endian: little", "encoding: raw",
            "space origin: (0,0,0)", "axis 3 index values:=" + " ".join(f"{t:g}" for t in ts)]
    return ("\n".join(head) + "\n\n").encode() + data


def _png(img: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", img)
    assert ok
    return buf.tobytes()


def _avi(images: np.ndarray, tmp: Path) -> bytes:
    import cv2

    w = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"MJPG"), 20,
                        (images.shape[2], images.shape[1]), False)
    for im in images:
        w.write(im)
    w.release()
    data = tmp.read_bytes()
    tmp.unlink()
    return data


def make_model(modality: str = "inplane", op: str = "sigmoid", in_shape=None, channels: int = 2,
               in_name: str = "image", out_name: str = "likelihood", meta: dict | None = None,
               drop: tuple[str, ...] = ()) -> bytes:
    """A tiny ONNX model: ``image`` -> ``likelihood``, ``channels`` copies of f(image). ``op``:
    sigmoid (a valid model), nan (0/0 everywhere), nan_bright (sqrt(-x): NaN where the
    normalised input is positive), inf, huge (x * 1e30), up2 / up64 (outputs 2x / 64x larger
    than the input), down4 (4x smaller), flatten (rank 2), int64 / double outputs, double
    input, two_outputs, badop (an operator that does not exist), slow (a loop of 10^12 steps).
    ``meta`` overrides the metadata; ``drop`` removes keys from it."""
    from onnx import TensorProto, helper

    nd = 3 if modality == "volume" else 2
    if in_shape is None:
        in_shape = ["N", 1] + ["D", "H", "W"][3 - nd:]
    elem = TensorProto.DOUBLE if op == "double_in" else TensorProto.FLOAT
    x = helper.make_tensor_value_info(in_name, elem, None if in_shape == "none" else
                                      list(in_shape))
    outs = [helper.make_tensor_value_info(out_name, TensorProto.FLOAT, None)]
    inits = []
    c = helper.make_node
    if op in ("sigmoid", "double_in", "two_outputs"):
        src = in_name
        if op == "double_in":
            nodes = [c("Cast", [in_name], ["xf"], to=TensorProto.FLOAT)]
            src = "xf"
        else:
            nodes = []
        nodes.append(c("Sigmoid", [src], ["m"]))
    elif op == "nan":
        nodes = [c("Sub", [in_name, in_name], ["z"]), c("Div", ["z", "z"], ["m"])]
    elif op == "nan_bright":
        nodes = [c("Neg", [in_name], ["n"]), c("Sqrt", ["n"], ["m"])]
    elif op == "inf":
        nodes = [c("Sub", [in_name, in_name], ["z"]), c("Abs", [in_name], ["a"]),
                 c("Div", ["a", "z"], ["m"])]
    elif op == "huge":
        inits.append(helper.make_tensor("k", TensorProto.FLOAT, [], [1e30]))
        nodes = [c("Mul", [in_name, "k"], ["m"])]
    elif op in ("up2", "up64", "down4"):
        f = {"up2": 2.0, "up64": 64.0, "down4": 0.25}[op]
        inits.append(helper.make_tensor("s", TensorProto.FLOAT, [2 + nd], [1, 1] + [f] * nd))
        nodes = [c("Sigmoid", [in_name], ["g"]), c("Resize", ["g", "", "s"], ["m"],
                                                     mode="nearest")]
    elif op == "flatten":
        nodes = [c("Sigmoid", [in_name], ["g"]), c("Flatten", ["g"], ["m"], axis=1)]
    elif op in ("int64", "double"):
        to = TensorProto.INT64 if op == "int64" else TensorProto.DOUBLE
        outs = [helper.make_tensor_value_info(out_name, to, None)]
        nodes = [c("Sigmoid", [in_name], ["g"]), c("Cast", ["g"], ["m"], to=to)]
    elif op == "badop":
        nodes = [c("NoSuchOperator", [in_name], ["m"])]
    elif op == "slow":  # a Loop of 10^12 iterations adding 1: the dry run never ends
        inits += [helper.make_tensor("n", TensorProto.INT64, [], [10**12]),
                  helper.make_tensor("t", TensorProto.BOOL, [], [True])]
        body = helper.make_graph(
            [c("Identity", ["cin"], ["cout"]), c("Add", ["acc", "one"], ["acc_out"])], "body",
            [helper.make_tensor_value_info("i", TensorProto.INT64, []),
             helper.make_tensor_value_info("cin", TensorProto.BOOL, []),
             helper.make_tensor_value_info("acc", TensorProto.FLOAT, None)],
            [helper.make_tensor_value_info("cout", TensorProto.BOOL, []),
             helper.make_tensor_value_info("acc_out", TensorProto.FLOAT, None)],
            [helper.make_tensor("one", TensorProto.FLOAT, [], [1.0])])
        nodes = [c("Loop", ["n", "t", in_name], ["m"], body=body)]
    else:
        raise ValueError(op)
    nodes.append(c("Concat", ["m"] * channels, [out_name], axis=1))
    if op == "two_outputs":
        nodes.append(c("Identity", ["m"], ["extra"]))
        outs.append(helper.make_tensor_value_info("extra", TensorProto.FLOAT, None))
    model = helper.make_model(helper.make_graph(nodes, "g", [x], outs, inits),
                              opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    md = {"modality": modality, "spacing_mm": json.dumps([0.2] * nd), "output_stride": "1",
          "input_multiple": "4", "target_reference": "centerline",
          "normalization": json.dumps({"mode": "fixed", "scale": 1 / 255, "mean": 0.35,
                                       "std": 0.25})}
    md.update(meta or {})
    helper.set_model_props(model, {k: v for k, v in md.items() if k not in drop})
    return model.SerializeToString()


class Base:
    """The valid inputs, made once per run (a few seconds); ``files`` maps a name to bytes."""

    def __init__(self, root: Path):
        import cv2

        import synth
        from needlenet.io import save_plus_sequence

        root = Path(root)
        root.mkdir(parents=True, exist_ok=True)
        self.root = root
        self._cache: dict = {}
        self.seqs = {k: synth.generate(scen, progress=False, **kw)
                     for k, (scen, kw) in SEQ_SPECS.items()}
        f: dict[str, bytes] = {}
        for k, s in self.seqs.items():
            f[f"{k}.npz"] = synth.save_sequence(s, root / f"{k}.npz", overwrite=True).read_bytes()
        for name, k, compress in (("i.seq.mha", "i", True), ("iu.seq.mha", "i", False),
                                  ("a.seq.mha", "a", True), ("v.seq.mha", "v", True),
                                  ("vu.seq.mha", "v", False), ("i.mhd", "i", False),
                                  ("iz.mhd", "i", True)):
            for p in save_plus_sequence(self.seqs[k], root / name, compress=compress,
                                        overwrite=True):
                f[p.name] = p.read_bytes()
        head, body = split_mha(f["iu.seq.mha"])
        fbody = (np.frombuffer(body, np.uint8).astype(np.float32) * 0.01 + 3.0).tobytes()
        f["if.seq.mha"] = join_mha(set_field(head, "ElementType", "MET_FLOAT"), fbody)
        s = self.seqs["i"]
        f["i.seq.nrrd"] = _nrrd_2d(s.images, s.spacing_mm, s.timestamps_s)
        f["ig.seq.nrrd"] = _nrrd_2d(s.images, s.spacing_mm, s.timestamps_s, encoding="gzip")
        det = _nrrd_2d(s.images, s.spacing_mm, s.timestamps_s)
        j = det.index(b"\n\n") + 2
        f["i.nhdr"] = det[:j - 1] + b"data file: i_data.raw\n"
        f["i_data.raw"] = det[j:]
        f["if.nrrd"] = _nrrd_2d(s.images.astype(np.float32) * 0.5, s.spacing_mm,
                                s.timestamps_s, dtype="float")
        v = self.seqs["v"]
        f["v.seq.nrrd"] = _nrrd_3d(v.images, v.spacing_mm, v.timestamps_s)
        for k, im in enumerate(s.images):
            f[f"frames/{k:03d}.png"] = f[f"bare/{k:03d}.png"] = _png(im)
        f["frames/frames.json"] = json.dumps(SIDECAR).encode()
        f["clip.avi"] = f["bare.avi"] = _avi(s.images, root / "tmp.avi")
        f["clip.json"] = json.dumps(SIDECAR).encode()
        for modality, name in MODELS.items():
            f[name] = make_model(modality)
        self.files = f
        assert cv2 is not None

    def cached(self, key, make):
        """``make()``, once per run."""
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def input_files(self, name: str) -> dict[str, bytes]:
        """The files of input ``name`` (copies)."""
        return {rel: self.files[rel] for rel in INPUTS[name][0]}


# -- text headers -----------------------------------------------------------------------------

def split_mha(data: bytes) -> tuple[list[list[str]], bytes]:
    """A MetaImage file as its header ``[key, value]`` lines and the bytes after them."""
    j = data.index(b"\n", data.index(b"ElementDataFile")) + 1
    lines = [ln.split(" = ", 1) for ln in data[:j].decode().splitlines()]
    return lines, data[j:]


def join_mha(lines, body: bytes = b"") -> bytes:
    return "".join(f"{k} = {v}\n" if v is not None else f"{k}\n"
                   for k, v in lines).encode() + body


def set_field(lines, key, value):
    out = [list(x) for x in lines]
    for x in out:
        if x[0] == key:
            x[1] = value
            return out
    pos = next((i for i, x in enumerate(out) if x[0] == "ElementDataFile"), len(out))
    out.insert(pos, [key, value])
    return out


def get_field(lines, key):
    return next((x[1] for x in lines if x[0] == key), None)


def remove_field(lines, key):
    return [list(x) for x in lines if x[0] != key]


def split_nrrd(data: bytes) -> tuple[list[str], bytes]:
    j = data.index(b"\n\n") + 2
    return data[:j].decode().splitlines()[:-1] if data[:j].endswith(b"\n\n") else \
        data[:j].decode().splitlines(), data[j:]


def join_nrrd(lines: list[str], body: bytes = b"") -> bytes:
    return ("\n".join(lines) + "\n\n").encode() + body


def nrrd_set(lines: list[str], key: str, value: str | None, custom: bool = False) -> list[str]:
    """Set (or with ``value`` None remove) field ``key`` of a NRRD header."""
    sep = ":=" if custom else ": "
    out, done = [], False
    for ln in lines:
        k = re.split(r":=|: ", ln, maxsplit=1)[0]
        if k == key and not done:
            done = True
            if value is not None:
                out.append(f"{key}{sep}{value}")
            continue
        out.append(ln)
    if not done and value is not None:
        out.append(f"{key}{sep}{value}")
    return out


# -- mutations --------------------------------------------------------------------------------

def pick(rng, seq):
    return seq[int(rng.integers(len(seq)))]


def mutate_bytes(data: bytes, rng, lo: int = 0, hi: int | None = None) -> tuple[bytes, str]:
    """One of: flip 1-32 bytes, cut the data, zero or 0xFF a run, insert or delete bytes,
    repeat a chunk; within ``data[lo:hi]``."""
    hi = len(data) if hi is None else hi
    b = bytearray(data)
    span = max(hi - lo, 1)
    op = pick(rng, ("flip", "flip", "flip", "cut", "cut", "zero", "ones", "insert", "delete",
                    "repeat"))
    at = lo + int(rng.integers(span))
    if op == "flip":
        k = int(rng.integers(1, 33))
        where = sorted(int(x) for x in lo + rng.integers(0, span, k))
        for w in where:
            if w < len(b):
                b[w] ^= int(rng.integers(1, 256))
        return bytes(b), f"{k} bytes flipped in {lo}-{hi} (first at {where[0]})"
    if op == "cut":
        return bytes(b[:at]), f"cut at byte {at} of {len(data)}"
    n = int(rng.integers(1, 4096))
    if op in ("zero", "ones"):
        b[at:at + n] = (b"\0" if op == "zero" else b"\xff") * len(b[at:at + n])
        return bytes(b), f"{n} bytes at {at} set to {op}"
    if op == "insert":
        return bytes(b[:at]) + rng.bytes(n) + bytes(b[at:]), f"{n} random bytes inserted at {at}"
    if op == "delete":
        return bytes(b[:at]) + bytes(b[at + n:]), f"{n} bytes deleted at {at}"
    return bytes(b[:at + n]) + bytes(b[at:]), f"{n} bytes repeated at {at}"


NUMBER_TEXT = ("0", "-1", "1", "2", "nan", "inf", "-inf", "1e-9", "1e9", "1e308", "1e400",
               "2147483648", "9223372036854775807", "99999999999999999999", "x", "", "1.5",
               "0x10", "1,2", "None")


def edit_numbers(value: str, rng) -> str:
    """A header's list of numbers with one entry replaced, one dropped or one added."""
    items = value.split()
    op = pick(rng, ("set", "set", "set", "drop", "add", "all", "empty"))
    if op == "empty":
        return ""
    if op == "drop" and items:
        del items[int(rng.integers(len(items)))]
    elif op == "add":
        items.append(pick(rng, ("1", "0", "5")))
    elif op == "all":
        items = [pick(rng, NUMBER_TEXT)] * len(items)
    elif items:
        k = int(rng.integers(len(items)))
        v = pick(rng, NUMBER_TEXT + ("+1", "-1*", "*2", "*1000"))
        try:
            n = int(items[k])
            v = {"+1": str(n + 1), "-1*": str(n - 1), "*2": str(n * 2),
                 "*1000": str(n * 1000)}.get(v, v)
        except ValueError:
            v = v if v not in ("+1", "-1*", "*2", "*1000") else "7"
        items[k] = v
    return " ".join(items)


def _track(inp: str, rng, extra=(), json_out=True, features=None) -> list[str]:
    args = ["track", "{d}/" + inp, "--quiet"]
    if json_out:
        args += ["--json", "{d}/out.json"]
    args += list(INPUTS[inp][2]) if inp in INPUTS else []
    feat = features or pick(rng, ("classical", "learned", "default"))
    if feat != "default":
        args += ["--features", feat]
    return args + list(extra)


def _case(family, what, argv, files, **kw) -> dict:
    outputs = kw.pop("outputs", ("out.json",))
    return {"family": family, "what": what, "argv": argv, "files": files, "outputs": outputs,
            **kw}


# -- families ---------------------------------------------------------------------------------

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


def _deep_json(n: int) -> str:
    return "[" * n + "]" * n


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
            arrays[key] = a[:0]
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


def _track_any(path: str, rng, extra=()) -> list[str]:
    args = ["track", "{d}/" + path, "--quiet", "--json", "{d}/out.json"]
    feat = pick(rng, ("classical", "learned", "default"))
    if feat != "default":
        args += ["--features", feat]
    return args + list(extra)


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


def fam_special(rng, base: Base) -> dict:
    """Special files where a recording is expected: FIFOs, devices, symlinks, folders named
    like files, empty files, files of another kind under the suffix."""
    choice = pick(rng, ("fifo", "fifo_png", "dev", "dir_named", "empty", "swap", "symlink_loop",
                        "nosuffix", "unicode", "png_folder_fifo_json"))
    files: dict[str, bytes] = {}
    fifos: tuple[str, ...] = ()
    links: dict[str, str] = {}
    ext = pick(rng, (".npz", ".seq.mha", ".mhd", ".nrrd", ".nhdr", ".avi", ".mp4"))
    name = "x" + ext
    extra = ["--spacing", "0.1", "--fps", "20"]
    if choice == "fifo":
        fifos = (name,)
        what = f"a FIFO named {name}"
    elif choice == "fifo_png":
        files = {k: v for k, v in base.input_files("frames").items()}
        fifos = ("frames/003b.png",)
        name = "frames"
        extra = []
        what = "a FIFO among the PNG frames"
    elif choice == "png_folder_fifo_json":
        files = {k: v for k, v in base.input_files("bare").items()}
        fifos = ("bare/frames.json",)
        name = "bare"
        what = "a FIFO as the sidecar"
    elif choice == "dev":
        links[name] = pick(rng, ("/dev/zero", "/dev/null", "/dev/urandom"))
        what = f"{name} -> {links[name]}"
    elif choice == "dir_named":
        files[name + "/"] = b""
        what = f"a folder named {name}"
    elif choice == "empty":
        files[name] = b""
        what = f"an empty {name}"
    elif choice == "swap":
        src = pick(rng, ("i.npz", "i.seq.mha", "i.seq.nrrd", "clip.avi", "m.onnx",
                         "frames/000.png"))
        files[name] = base.files[src]
        what = f"{src} named {name}"
    elif choice == "symlink_loop":
        links[name] = "{d}/" + name
        what = f"{name}: a symlink to itself"
    elif choice == "nosuffix":
        name = pick(rng, ("x", "x.", "x.NPZ", "x.Seq.MHA", "x.txt", ".npz"))
        files[name] = base.files["i.npz"] if "npz" in name.lower() else base.files["i.seq.mha"]
        what = f"a recording named {name!r}"
    else:
        name = "ünï cødé ✓" + ext
        files[name] = base.files["i.npz"] if ext == ".npz" else b"junk"
        what = f"unicode name {name!r}"
    argv = ["track", "{d}/" + name, "--quiet", "--json", "{d}/out.json", *extra]
    return _case("special", what, argv, files, fifos=fifos, links=links)


def deflate_zeros(prefix: bytes, n_mib: int) -> bytes:
    """A raw deflate stream of ``prefix`` then ``n_mib`` MiB of zeros, made in milliseconds:
    after a full flush the compressor emits the same bytes for every further MiB of zeros,
    so one such block is repeated (about 1000:1)."""
    c = zlib.compressobj(9, zlib.DEFLATED, -15)
    z = bytes(1 << 20)
    head = c.compress(prefix) + c.flush(zlib.Z_FULL_FLUSH)
    first = c.compress(z) + c.flush(zlib.Z_FULL_FLUSH)
    block = c.compress(z) + c.flush(zlib.Z_FULL_FLUSH)
    assert block == c.compress(z) + c.flush(zlib.Z_FULL_FLUSH)
    return head + first + block * (n_mib - 1) + c.flush(zlib.Z_FINISH)


def zip_bytes(members: list[tuple]) -> bytes:
    """A zip archive from ``(name, data, method, crc, compressed size, size)`` as given (the
    sizes may be forged: that is the point)."""
    out, central = bytearray(), bytearray()
    for name, data, method, crc, csize, usize in members:
        nb = name.encode()
        offset = len(out)
        out += struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, method, 0, 0x21, crc, csize,
                           usize, len(nb), 0) + nb + data
        central += struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, method, 0, 0x21,
                               crc, csize, usize, len(nb), 0, 0, 0, 0, 0, offset) + nb
    n = len(members)
    return bytes(out + central + struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, n, n, len(central),
                                             len(out), 0))


def _npz_members(data: bytes) -> list[tuple]:
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        out = []
        for info in z.infolist():
            raw = z.read(info.filename)
            c = zlib.compressobj(6, zlib.DEFLATED, -15)
            comp = c.compress(raw) + c.flush()
            out.append((info.filename, comp, 8, zlib.crc32(raw), len(comp), len(raw)))
    return out


def fam_bomb(rng, base: Base) -> dict:
    """Small files that claim or inflate to gigabytes: a reader that trusts them allocates
    it all. Forged zip sizes, a deflate bomb in an npz, a gzip NRRD and a compressed PLUS
    file inflating to 2.5 GiB, a PNG whose header claims 30000^2 pixels."""
    choice = pick(rng, ("npz_forged", "npz_bomb", "nrrd_gzip", "plus", "png", "plus_dims"))
    s = base.seqs["i"]
    T = s.n_frames
    if choice == "npz_forged":  # the npy header and the zip directory agree on 4.2 GB
        members = [m for m in _npz_members(base.files["i.npz"]) if m[0] != "images.npy"]
        head = _npy_header((8, 16384, 32000))
        body = head + bytes(100)
        c = zlib.compressobj(6, zlib.DEFLATED, -15)
        comp = c.compress(body) + c.flush()
        # the CRC of what the stream holds (zipfile checks it as soon as the stream ends)
        members.append(("images.npy", comp, 8, zlib.crc32(body), len(comp),
                        len(head) + 8 * 16384 * 32000))
        return _case("bomb", "i.npz: images.npy's npy header and zip sizes claim 4.2 GB in "
                     f"{len(comp)} bytes", _track("i.npz", rng), {"i.npz": zip_bytes(members)})
    if choice == "npz_bomb":  # an honest deflate stream of 2.5 GiB of zeros
        members = [m for m in _npz_members(base.files["i.npz"]) if m[0] != "images.npy"]
        shape = (10, 16384, 16384)
        head = _npy_header(shape)
        comp = base.cached(("npz_bomb",), lambda: deflate_zeros(head, 2560))
        members.append(("images.npy", comp, 8, 0, len(comp), len(head) + 10 * 16384 * 16384))
        return _case("bomb", f"i.npz: images.npy deflates from {len(comp)} bytes to 2.5 GiB",
                     _track("i.npz", rng), {"i.npz": zip_bytes(members)})
    if choice == "nrrd_gzip":
        lines, _ = split_nrrd(base.files["i.seq.nrrd"])
        raw = base.cached(("gz",), lambda: deflate_zeros(b"", 2560))
        gz = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\x03" + raw + struct.pack(
            "<II", 0, (2560 << 20) & 0xFFFFFFFF)
        return _case("bomb", f"i.seq.nrrd: gzip data of {len(gz)} bytes inflating to 2.5 GiB "
                     "(sizes say 60 kB)", _track("i.seq.nrrd", rng),
                     {"i.seq.nrrd": join_nrrd(nrrd_set(lines, "encoding", "gzip"), gz)})
    if choice in ("plus", "plus_dims"):
        head, _ = split_mha(base.files["i.seq.mha"])
        raw = base.cached(("gz",), lambda: deflate_zeros(b"", 2560))
        blob = b"\x78\xda" + raw + b"\0\0\0\0"
        dims = "16384 16384 10" if choice == "plus" else f"{s.images.shape[2]} " \
            f"{s.images.shape[1]} {T}"
        head = set_field(set_field(head, "DimSize", dims), "CompressedDataSize", str(len(blob)))
        return _case("bomb", f"i.seq.mha: zlib data of {len(blob)} bytes inflating to 2.5 GiB, "
                     f"DimSize = {dims}", _track("i.seq.mha", rng),
                     {"i.seq.mha": join_mha(head, blob)})
    files = base.input_files("frames")
    k = pick(rng, sorted(n for n in files if n.endswith(".png")))
    files[k] = png_claiming(30000, 30000, 8, 0)
    return _case("bomb", f"frames: {k} claims 30000 x 30000 pixels", _track("frames", rng),
                 files)


def fam_control(rng, base: Base) -> dict:
    """Valid inputs, each with its usual options: these must track (exit 0), and their
    --json must hold finite numbers."""
    inp = pick(rng, sorted(INPUTS))
    extra = []
    if rng.random() < 0.3 and INPUTS[inp][1] == "inplane":
        extra = ["--method", pick(rng, ("kf", "pf+f", "df", "line", "kfv+f", "om"))]
    if rng.random() < 0.2:
        extra += ["--overlay", "{d}/o.gif"]
    return _case("control", f"valid {inp} {' '.join(extra)}", _track(inp, rng, extra),
                 base.input_files(inp), outputs=("out.json", "o.gif"), expect=("ok",))


FAMILIES = {
    "npz-bytes": fam_npz_bytes, "npz-arrays": fam_npz_arrays, "plus-header": fam_plus_header,
    "plus-bytes": fam_plus_bytes, "pixels": fam_pixels, "nrrd-header": fam_nrrd_header,
    "nrrd-bytes": fam_nrrd_bytes, "frames": fam_frames, "video": fam_video, "model": fam_model,
    "param": fam_param, "options": fam_options, "output": fam_output, "synth": fam_synth,
    "special": fam_special, "control": fam_control, "bomb": fam_bomb,
}
# one round of the schedule: the families weighted by how many distinct fields they touch
SCHEDULE = ("plus-header", "npz-arrays", "param", "output", "model", "options", "nrrd-header",
            "frames", "plus-header", "npz-bytes", "video", "synth", "pixels", "plus-bytes",
            "npz-arrays", "param", "output", "model", "options", "nrrd-bytes", "plus-header",
            "frames", "nrrd-header", "special", "control", "plus-header", "npz-arrays",
            "param", "output", "model", "options", "video", "synth", "pixels", "nrrd-header",
            "frames", "plus-bytes", "npz-bytes", "plus-header", "output", "param", "model",
            "options", "npz-arrays", "nrrd-bytes", "special", "control", "synth", "bomb")


def make_case(seed: int, index: int, base: Base) -> Case:
    """Case ``index`` of ``seed``: its family from :data:`SCHEDULE`, its draws from
    ``default_rng([seed, index])``."""
    family = SCHEDULE[index % len(SCHEDULE)]
    rng = np.random.default_rng([seed, index])
    spec = FAMILIES[family](rng, base)
    spec["family"] = family
    return Case(id=f"{index:05d}-{family}", **spec)


def generate_cases(n: int, seed: int, base: Base, only=None) -> Iterator[Case]:
    """The first ``n`` cases of ``seed`` (or only the indices in ``only``)."""
    for i in (range(n) if only is None else sorted(only)):
        yield make_case(seed, i, base)
