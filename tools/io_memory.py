"""Peak memory of ``needlenet track`` on long recordings: writes 500 x 384 uint8 recordings of
a given length as an uncompressed PLUS ``.mha`` (and a compressed one), a raw NRRD and a folder
of PNG frames (the frames of one seeded in-plane sequence, repeated), then runs

    /usr/bin/time -v needlenet track FILE --spacing 0.1 --features classical --quiet

on each and prints the maximum resident set size and the wall time.

    python tools/io_memory.py write /tmp/io_mem 300 10000 --png 2000 [--compressed]
    python tools/io_memory.py measure /tmp/io_mem
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import numpy as np


def _base_frames(seed: int = 1) -> np.ndarray:
    import synth

    return synth.generate("inplane", seed=seed).images  # (T, 500, 384) uint8


def _frames(base: np.ndarray, n: int):
    """``n`` frames cycling through ``base`` (forwards then backwards, so the needle moves
    smoothly), one at a time."""
    cycle = np.concatenate([np.arange(len(base)), np.arange(len(base) - 2, 0, -1)])
    for i in range(n):
        yield base[cycle[i % len(cycle)]]


def write_plus(path: Path, base: np.ndarray, n: int, fps: float = 20.0,
               compress: bool = False) -> None:
    """A PLUS sequence metafile, written frame by frame (compressed: one zlib stream, made
    in a temporary file first since the header gives its size)."""
    import shutil
    import tempfile
    import zlib

    H, W = base.shape[1:]
    spool = tempfile.TemporaryFile()
    if compress:
        z = zlib.compressobj(1)
        for f in _frames(base, n):
            spool.write(z.compress(f.tobytes()))
        spool.write(z.flush())
    lines = ["ObjectType = Image", "NDims = 3", "BinaryData = True",
             "BinaryDataByteOrderMSB = False", f"CompressedData = {compress}"]
    lines += [f"CompressedDataSize = {spool.tell()}"] if compress else []
    lines += [f"DimSize = {W} {H} {n}", "ElementNumberOfChannels = 1",
             "ElementSpacing = 0.1 0.1 1", "ElementType = MET_UCHAR",
             "Kinds = domain domain list", "Offset = 0 0 0",
             "UltrasoundImageOrientation = MF", "UltrasoundImageType = BRIGHTNESS"]
    lines += [f"Seq_Frame{i:04d}_Timestamp = {i / fps!r}" for i in range(n)]
    lines += [f"Seq_Frame{i:04d}_ImageStatus = OK" for i in range(n)]
    with open(path, "wb") as fh:
        fh.write(("\n".join(lines) + "\nElementDataFile = LOCAL\n").encode())
        if compress:
            spool.seek(0)
            shutil.copyfileobj(spool, fh)
        else:
            for f in _frames(base, n):
                fh.write(f.tobytes())
    spool.close()


def write_nrrd(path: Path, base: np.ndarray, n: int, fps: float = 20.0) -> None:
    """A raw NRRD sequence (kinds domain domain list), written frame by frame."""
    H, W = base.shape[1:]
    head = ("NRRD0004\ntype: uint8\ndimension: 3\n"
            f"sizes: {W} {H} {n}\nkinds: domain domain list\nencoding: raw\n"
            "space dimension: 2\nspace directions: (0.1,0) (0,0.1) none\n"
            f"axis 2 index values: {' '.join(repr(i / fps) for i in range(n))}\n\n")
    with open(path, "wb") as fh:
        fh.write(head.encode())
        for f in _frames(base, n):
            fh.write(f.tobytes())


def write_png(folder: Path, base: np.ndarray, n: int) -> None:
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(_frames(base, n)):
        cv2.imwrite(str(folder / f"f{i:05d}.png"), f)


def write(out: Path, lengths: list[int], png: int | None, compressed: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    base = _base_frames()
    for n in lengths:
        write_plus(out / f"rec{n}.mha", base, n)
        write_nrrd(out / f"rec{n}.nrrd", base, n)
        print(f"wrote {out}/rec{n}.mha and .nrrd", flush=True)
        if compressed:
            write_plus(out / f"rec{n}z.mha", base, n, compress=True)
            print(f"wrote {out}/rec{n}z.mha", flush=True)
    for n in sorted({min(png or max(lengths), n) for n in lengths}):
        write_png(out / f"png{n}", base, n)
        print(f"wrote {out}/png{n}/ ({n} PNG frames)", flush=True)


def measure(out: Path, extra: list[str]) -> list[dict]:
    rows = []
    recs = sorted(out.glob("rec*.mha"), key=lambda p: int(re.sub(r"\D", "", p.stem))) + \
        sorted(out.glob("rec*.nrrd"), key=lambda p: int(re.sub(r"\D", "", p.stem))) + \
        sorted(out.glob("png*"), key=lambda p: int(re.sub(r"\D", "", p.name)))
    for rec in recs:
        cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "needlenet", "track", str(rec),
               "--spacing", "0.1", "--features", "classical", "--quiet"]
        if rec.is_dir():
            cmd += ["--fps", "20"]
        r = subprocess.run(cmd + extra, capture_output=True, text=True)
        rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
        wall = re.search(r"Elapsed \(wall clock\) time.*: ([\d:.]+)", r.stderr)
        row = {"file": rec.name, "rc": r.returncode,
               "max_rss_mb": int(rss.group(1)) / 1024 if rss else None,
               "wall": wall.group(1) if wall else None}
        if r.returncode:
            row["error"] = r.stderr.strip().splitlines()[:3]
        rows.append(row)
        print(row, flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    w = sub.add_parser("write")
    w.add_argument("out", type=Path)
    w.add_argument("lengths", type=int, nargs="+")
    w.add_argument("--png", type=int, help="at most this many PNG frames per folder")
    w.add_argument("--compressed", action="store_true",
                   help="also a compressed PLUS file of each length (recNz.mha)")
    m = sub.add_parser("measure")
    m.add_argument("out", type=Path)
    m.add_argument("extra", nargs="*", help="more needlenet track options")
    a = ap.parse_args(argv)
    if a.cmd == "write":
        write(a.out, a.lengths, a.png, a.compressed)
    else:
        measure(a.out, a.extra)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
