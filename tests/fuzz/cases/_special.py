"""Case families: special files, bombs, and valid controls."""

from __future__ import annotations

import io
import struct
import zipfile
import zlib

from ._base import (
    INPUTS,
    Base,
    _case,
    _track,
    join_mha,
    join_nrrd,
    nrrd_set,
    pick,
    set_field,
    split_mha,
    split_nrrd,
)
from ._npz_plus import _npy_header
from ._nrrd_frames import png_claiming


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
