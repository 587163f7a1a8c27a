"""The valid inputs every case starts from, the case record, and the helpers that edit
headers and bytes."""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

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
    "i.dcm": (("i.dcm",), "inplane", ()),
    "IM_0001": (("IM_0001",), "inplane", ()),
    "ic.dcm": (("ic.dcm",), "inplane", ()),
    "ir.dcm": (("ir.dcm",), "inplane", ()),
    "series": (tuple(f"series/IM_{k:04d}" for k in range(1, 6)), "inplane", ()),
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
        from ._dicom import dicom_inputs

        f.update(dicom_inputs(s, root))
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


def _deep_json(n: int) -> str:
    return "[" * n + "]" * n


def _track_any(path: str, rng, extra=()) -> list[str]:
    args = ["track", "{d}/" + path, "--quiet", "--json", "{d}/out.json"]
    feat = pick(rng, ("classical", "learned", "default"))
    if feat != "default":
        args += ["--features", feat]
    return args + list(extra)
