"""Where a PLUS sequence metafile's pixels are and how they are read: the data file and
offset named by the header (``ElementDataFile``, ``HeaderSize``), checked against the sizes
the header describes, then read whole, memory-mapped (uncompressed) or inflated as one zlib
stream (``CompressedData``); see :mod:`._metaimage` for the format."""

from __future__ import annotations

import math
import os
import zlib
from pathlib import Path

import numpy as np

from ._errors import RecordingError
from ._lazy import ZlibStream

__all__ = ["header_numbers", "data_file", "raw_span", "compressed_span", "check_inflated",
           "pixel_bytes", "first_frame"]

_MAX_INFLATION = 1032  # deflate inflates at most ~1032:1 (a 258-byte match costs >= 2 bits)


def header_numbers(header: dict, key: str, src: str, count: int | None = None,
             kind=float) -> np.ndarray:
    try:
        v = np.array([kind(s) for s in header[key].split()])
    except ValueError:
        raise RecordingError(f"{src}: field {key} = {header[key]!r} is not a list of numbers"
                             ) from None
    if count is not None and v.size != count:
        raise RecordingError(f"{src}: field {key} has {v.size} values, expected {count}")
    if kind is float and not np.all(np.isfinite(v)):
        raise RecordingError(f"{src}: field {key} = {header[key]!r} is not finite")
    return v


def data_file(path: Path, src: str, header: dict, offset: int) -> tuple[Path, int]:
    """The file holding the pixels and where they start in it (-1: they are its last
    bytes)."""
    data_file = header["ElementDataFile"]
    if data_file == "LOCAL":
        return path, offset
    if data_file.upper() == "LIST" or "%" in data_file or len(data_file.split()) > 1:
        raise RecordingError(f"{src}: ElementDataFile = {data_file!r}: one data file per "
                             "frame is not supported; write the sequence as one .mha")
    target = (path.parent / data_file)
    if not target.is_file():
        raise RecordingError(f"{src}: ElementDataFile {data_file}: no such file next to "
                             "the header")
    skip = int(header_numbers(header, "HeaderSize", src, 1, int)[0]) if "HeaderSize" in \
        header else 0
    return target, skip


def raw_span(path: Path, src: str, header: dict, offset: int,
              nbytes: int) -> tuple[Path, int] | None:
    """The file and offset of ``nbytes`` of uncompressed pixels, or None when the file does
    not hold exactly that many after the header (:func:`pixel_bytes` says how)."""
    try:
        target, skip = data_file(path, src, header, offset)
    except RecordingError:
        return None
    size = os.path.getsize(target)
    start = skip if skip >= 0 else size - nbytes
    return (target, start) if start >= 0 and size - start == nbytes else None


def compressed_span(path: Path, src: str, header: dict, offset: int,
                     nbytes: int) -> tuple[Path, int, int]:
    """The file holding the zlib stream of the pixels, where it starts and its length in
    bytes, checked against ``CompressedDataSize`` and what zlib can inflate to ``nbytes``."""
    target, skip = data_file(path, src, header, offset)
    size = os.path.getsize(target)
    tsrc = str(target)
    csize = int(header_numbers(header, "CompressedDataSize", src, 1, int)[0]) \
        if "CompressedDataSize" in header else None
    if csize is not None and csize < 1:
        raise RecordingError(f"{src}: CompressedDataSize = {csize} must be positive")
    start = skip if skip >= 0 else size - (csize or 0)
    avail = size - start
    if csize is not None and avail < csize:
        raise RecordingError(
            f"{tsrc}: truncated: CompressedDataSize = {csize} but only {avail} bytes "
            "of pixel data follow the header")
    if start < 0 or avail < 1:
        raise RecordingError(f"{tsrc}: no compressed pixel data after the header")
    if nbytes > _MAX_INFLATION * (csize if csize is not None else avail) + 1024:
        raise RecordingError(
            f"{tsrc}: DimSize/ElementType need {nbytes} bytes of pixels, more than "
            f"zlib can inflate from the {csize or avail} compressed bytes given; "
            "damaged header?")
    return target, start, csize if csize is not None else avail


def _inflated_size_error(tsrc: str, nbytes: int, got: int) -> RecordingError:
    return RecordingError(
        f"{tsrc}: the header's DimSize/ElementType need {nbytes} bytes of pixels "
        f"but the compressed data holds {'more' if got > nbytes else got}"
        + ("" if got > nbytes else " (truncated file?)"))


def check_inflated(stream: ZlibStream, nbytes: int, tsrc: str) -> None:
    """The stream inflates to exactly ``nbytes``: counted 1 MiB at a time, kept nowhere."""
    total = 0
    try:
        while total <= nbytes:
            piece = stream.next_bytes(min(1 << 20, nbytes + 1 - total))
            if not piece:
                break
            total += len(piece)
    except zlib.error as exc:
        raise RecordingError(f"{tsrc}: compressed pixel data is damaged ({exc})") from None
    if total != nbytes:
        raise _inflated_size_error(tsrc, nbytes, total)
    stream.restart()


def pixel_bytes(path: Path, src: str, header: dict, offset: int, nbytes: int,
                 compressed: bool) -> bytes:
    """The pixel data as bytes, checking sizes against the header."""
    if compressed:
        target, start, length = compressed_span(path, src, header, offset, nbytes)
        with open(target, "rb") as fh:
            fh.seek(start)
            blob = fh.read(length)
        try:
            d = zlib.decompressobj()
            out = d.decompress(blob, nbytes + 1)
            if len(out) <= nbytes and not d.eof:
                out += d.flush()
        except zlib.error as exc:
            raise RecordingError(f"{target}: compressed pixel data is damaged ({exc})"
                                 ) from None
        if len(out) != nbytes:
            raise _inflated_size_error(str(target), nbytes, len(out))
        return out
    target, skip = data_file(path, src, header, offset)
    size = os.path.getsize(target)
    start = skip if skip >= 0 else size - nbytes
    avail = size - start
    if avail != nbytes or start < 0:
        what = "truncated" if avail < nbytes else "sizes do not match the data"
        raise RecordingError(
            f"{target}: {what}: DimSize/ElementType/ElementNumberOfChannels need {nbytes} "
            f"bytes of pixels, the file has {max(avail, 0)} after the header")
    with open(target, "rb") as fh:
        fh.seek(start)
        return fh.read(nbytes)


def first_frame(span: tuple[Path, int], shape: tuple, dtype: np.dtype) -> np.ndarray:
    """The first frame's raw pixels, ``(1, *shape[1:])``."""
    n = math.prod(shape[1:]) * dtype.itemsize
    with open(span[0], "rb") as fh:
        fh.seek(span[1])
        return np.frombuffer(fh.read(n), dtype).reshape((1, *shape[1:]))
