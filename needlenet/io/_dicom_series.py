"""A folder of single-frame DICOM files as one recording: a scanner that stores a clip as one
image per instance (an export folder of ``IM_0001``, ``IM_0002``, ... beside a ``DICOMDIR``).

The files must be one series of single 2D frames of one size and pixel format; they are
ordered by ``InstanceNumber`` (the file names' natural order breaks ties and stands in where
a file has none). The geometry is the first file's (its ultrasound region, or PixelSpacing:
:mod:`._dicom`), and every file's must agree. Frame times are each file's acquisition time
(``AcquisitionDateTime``, else ``AcquisitionTime``, else ``ContentTime``) less the first's;
without them on every file, or when they do not increase, the caller asks for ``--fps``. A
folder holding cine loops (multi-frame files) names one to track instead: each is a
recording. Frames are decoded as they are read, a file each.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ._dicom import (
    DicomRecording,
    _decoder,
    _geometry,
    _header,
    _int,
    _pixel_format,
    _quiet_pydicom,
    dicom_meta,
    is_dicom,
)
from ._errors import RecordingError
from ._frames import _natural_key
from ._lazy import FrameStack
from ._limits import check_allocation, check_frame_shape

__all__ = ["dicom_files", "read_dicom_series"]

MAX_FILES = 100_000  # frames of one clip: an hour at 25 frames/s and more


def dicom_files(folder: Path) -> list[Path]:
    """The DICOM files of ``folder`` (DICOM's signature; the ``DICOMDIR`` index left out), in
    natural order of their names."""
    out = []
    for p in sorted(Path(folder).iterdir(), key=_natural_key):
        if len(out) > MAX_FILES:
            raise RecordingError(f"{folder}: more than {MAX_FILES} DICOM files")
        if p.name.upper() != "DICOMDIR" and p.is_file() and is_dicom(p):
            out.append(p)
    return out


def read_dicom_series(folder: Path, files: list[Path]) -> DicomRecording:
    """The single-frame DICOM ``files`` of ``folder`` as one recording (see the module's
    doc); a RecordingError naming the file that does not fit."""
    with _quiet_pydicom():
        return _read_series(Path(folder), files)


def _read_series(folder: Path, files: list[Path]) -> DicomRecording:
    notes: list[str] = []
    heads = [_header(str(f), notes) for f in files]
    loops = [f.name for f, ds in zip(files, heads, strict=True)
             if _int(ds, "NumberOfFrames", str(f), default=1) != 1]
    if loops:
        raise RecordingError(
            f"{folder}: holds {len(loops)} DICOM cine loop{'s' * (len(loops) != 1)} "
            f"(multi-frame files); each is a recording: track one, e.g. {folder / loops[0]}")
    series = {str(ds.get("SeriesInstanceUID", "")) for ds in heads}
    if len(series) > 1:
        raise RecordingError(f"{folder}: holds DICOM frames of {len(series)} series; put the "
                             "frames of one clip in a folder of their own")
    order = sorted(range(len(files)),
                   key=lambda i: (_instance(heads[i], str(files[i])), _natural_key(files[i])))
    files, heads = [files[i] for i in order], [heads[i] for i in order]
    first, src0 = heads[0], str(files[0])
    shape, channels, bits = _pixel_format(first, src0)
    check_frame_shape(shape, src0, "Rows x Columns")
    check_allocation((*shape, channels), max(bits // 8, 1), src0, "Rows x Columns")
    spacing, origin, crop, note = _geometry(first, src0, shape)
    notes += [note] if note else []
    decoders = [_decoder(first, src0)]
    for f, ds in zip(files[1:], heads[1:], strict=True):
        if _pixel_format(ds, str(f)) != (shape, channels, bits):
            raise RecordingError(f"{f}: {_describe(ds)}, but {files[0].name} has "
                                 f"{_describe(first)}")
        sp, _, cr, _ = _geometry(ds, str(f), shape)
        if not _same(sp, spacing) or cr != crop:
            raise RecordingError(f"{f}: its spacing or image region differs from "
                                 f"{files[0].name}'s (the scanner's depth changed within the "
                                 "clip?)")
        decoders.append(_decoder(ds, str(f)))
    stack = FrameStack(lambda i: decoders[i].read(0), len(files), shape, source=files)
    stack.frame(0)
    meta = dicom_meta(first, decoders[0], len(files), spacing, crop)
    meta["dicom"]["files"] = len(files)
    return DicomRecording(stack, spacing, origin, crop, _times(heads), meta, notes)


def _instance(ds, src: str) -> int:
    n = ds.get("InstanceNumber")
    return _int(ds, "InstanceNumber", src) if n is not None else 1 << 62


def _describe(ds) -> str:
    return (f"{ds.get('Columns')}x{ds.get('Rows')} pixels of {ds.get('SamplesPerPixel', 1)} "
            f"x {ds.get('BitsAllocated')} bits")


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.allclose(a, b, rtol=1e-6, atol=0.0))


def _times(heads) -> np.ndarray | None:
    """Each frame's acquisition time less the first's (s), or None where a file has none or
    the times do not increase."""
    ts = []
    for ds in heads:
        t = _seconds(ds)
        if t is None:
            return None
        ts.append(t)
    ts = np.asarray(ts) - ts[0]
    return ts if len(ts) == 1 or np.all(np.diff(ts) > 0) else None


def _seconds(ds) -> float | None:
    """Seconds since midnight from AcquisitionDateTime (YYYYMMDDHHMMSS.FFFFFF),
    AcquisitionTime or ContentTime (HHMMSS.FFFFFF); None without a readable one."""
    for key, skip in (("AcquisitionDateTime", 8), ("AcquisitionTime", 0), ("ContentTime", 0)):
        v = ds.get(key)
        if v is None:
            continue
        m = re.fullmatch(r"(\d{2})(\d{2})?(\d{2})?(\.\d{1,6})?", str(v).strip()[skip:][:13])
        if m is None:
            continue
        h, mi, se = (int(g) if g else 0 for g in m.group(1, 2, 3))
        frac = float(m.group(4)) if m.group(4) else 0.0
        if h < 24 and mi < 60 and se < 61:
            return h * 3600.0 + mi * 60.0 + se + frac
    return None
