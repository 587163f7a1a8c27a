"""DICOM ultrasound recordings: a scanner's exported cine loop (multi-frame) or single frame.

What a clinical scanner exports, read with its own geometry so that the user need not measure
it on the screen:

- **pixel spacing, origin and image area** from the Sequence of Ultrasound Regions (0018,6011):
  the region holding the 2D tissue image (data type 1, spatial format 1; of several, the
  largest) gives mm per pixel (``PhysicalDeltaY`` and ``PhysicalDeltaX``, in cm), its
  bounding box the crop that cuts away the scanner's text, scales and thumbnails, and its
  reference pixel the physical position of the image (``ReferencePixelPhysicalValueX/Y`` at
  ``ReferencePixelX0/Y0``). Without a usable region, ``Pixel Spacing`` (0028,0030) when the
  file has one; otherwise no spacing, and the caller asks for ``--spacing``;
- **frame times** from ``Frame Time Vector`` (0018,1065) or ``Frame Time`` (0018,1063), in
  ms, else ``Cine Rate`` or ``Recommended Display Frame Rate`` (frames/s);
- **pixels**, decoded a frame at a time as the tracker reads them (uncompressed and RLE by
  pydicom, JPEG baseline by OpenCV's libjpeg, JPEG extended and JPEG 2000 by Pillow), as
  uint8 gray: colour (RGB, the YBR of a JPEG-compressed loop, or a palette image through its
  colour tables) as luma with the scanner's coloured marks filled in (as for videos),
  ``MONOCHROME1`` inverted, more than 8 bits scaled from their stored range.

Transfer syntaxes Pillow cannot decode (JPEG lossless, JPEG-LS) are refused with the syntax
named and a way to convert the file; so are 3D volumes stored as one multi-frame DICOM.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._errors import RecordingError
from ._frames import _gray
from ._lazy import FrameStack
from ._limits import check_allocation, check_frame_shape

__all__ = ["DicomRecording", "is_dicom", "read_dicom", "DICOM_SUFFIXES"]

DICOM_SUFFIXES = (".dcm", ".dicom", ".dic")
_CM = 3  # PhysicalUnitsX/YDirection: centimetres
_TISSUE, _SPATIAL_2D = 1, 1  # RegionDataType, RegionSpatialFormat
# SOP classes that hold a 3D volume in their frames (not a 2D cine loop)
_VOLUME_SOPS = {"1.2.840.10008.5.1.4.1.1.6.2": "Enhanced US Volume"}


@dataclass
class DicomRecording:
    """What :func:`read_dicom` found: ``images`` (T, H, W) uint8 gray, read on access;
    ``spacing_mm`` (depth, lateral) and ``origin_mm`` of the whole frame, or None where the
    file does not say; ``crop`` (x, y, w, h) of the tissue region, or None; ``timestamps_s``
    or None; ``meta`` for the sequence's meta; ``notes`` for the user."""

    images: FrameStack
    spacing_mm: np.ndarray | None
    origin_mm: np.ndarray | None
    crop: tuple[int, int, int, int] | None
    timestamps_s: np.ndarray | None
    meta: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


class _ClampedFile(io.BufferedReader):
    """A file whose reads never ask for more than is left in it: a damaged element length
    of gigabytes is then a short read (which pydicom reports), not a buffer of gigabytes
    allocated before the read."""

    def __init__(self, path: str):
        super().__init__(io.FileIO(path, "rb"))
        self._size = os.fstat(self.fileno()).st_size

    def read(self, n: int | None = -1) -> bytes:
        if n is not None and n > 0:
            n = min(n, max(self._size - self.tell(), 0))
            if n == 0:
                return b""
        return super().read(n)


@contextlib.contextmanager
def _quiet_pydicom():
    """pydicom without its value checks' warnings and log lines (one per odd value, printed
    by the thousand for a damaged file): needlenet checks what it reads and says what is
    wrong in one error."""
    from pydicom import config

    mode = config.settings.reading_validation_mode
    logger = logging.getLogger("pydicom")
    level = logger.level
    config.settings.reading_validation_mode = config.IGNORE
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        config.settings.reading_validation_mode = mode
        logger.setLevel(level)


def _readable(ds, src: str, notes: list[str], where: str = "") -> None:
    """Convert every element of ``ds`` (and of its sequences' items) now; one that cannot
    be (a damaged value representation or value) is dropped, and a note says which. What
    needlenet needs of a dropped element is then missing, and its check names it."""
    dropped = []
    for tag in list(ds.keys()):
        try:
            elem = ds[tag]
            if elem.VR == "SQ":
                for k, item in enumerate(elem.value):
                    _readable(item, src, notes, f"{where}{elem.keyword or tag}[{k}].")
        except Exception:
            del ds[tag]
            dropped.append(f"{where}{tag}")
    if dropped:
        notes.append(f"{src}: {len(dropped)} damaged DICOM attributes ignored (first: "
                     f"{dropped[0]})")


def is_dicom(path: str | os.PathLike) -> bool:
    """Whether a file carries DICOM's Part 10 signature ("DICM" after a 128-byte preamble),
    the way a scanner's export names no suffix (``IM_0001``)."""
    try:
        with open(path, "rb") as f:
            head = f.read(132)
    except OSError:
        return False
    return len(head) == 132 and head[128:] == b"DICM"


def read_dicom(path: str | os.PathLike) -> DicomRecording:
    """Read a DICOM ultrasound file (see the module's doc); a :class:`RecordingError` naming
    the file and the attribute at fault for anything needlenet cannot read."""
    with _quiet_pydicom():
        return _read(path)


def _read(path: str | os.PathLike) -> DicomRecording:
    src = str(path)
    notes: list[str] = []
    ds = _header(src, notes)
    shape, channels, bits = _pixel_format(ds, src)
    decode = _decoder(ds, src)
    n = _int(ds, "NumberOfFrames", src, default=1)
    if n < 1:
        raise RecordingError(f"{src}: NumberOfFrames (0028,0008) is {n}")
    check_frame_shape(shape, src, "Rows x Columns")
    check_allocation((*shape, channels), max(bits // 8, 1), src, "Rows x Columns")
    _check_frame_count(n, shape, channels, bits, decode.compressed, src)
    spacing, origin, crop, region_note = _geometry(ds, src, shape)
    if region_note:
        notes.append(region_note)
    meta = dicom_meta(ds, decode, n, spacing, crop)
    stack = FrameStack(decode.read, n, shape, source=src)
    stack.frame(0)  # the first frame decodes, or the error names why now
    return DicomRecording(stack, spacing, origin, crop, _frame_times(ds, n, src), meta, notes)


def dicom_meta(ds, decode, n: int, spacing, crop) -> dict:
    """What the sequence's meta records of a DICOM recording."""
    return {"format": "dicom",
            "dicom": {"transfer_syntax": decode.syntax, "photometric": decode.photometric,
                      "sop_class": str(ds.get("SOPClassUID", "")), "frames": n,
                      "manufacturer": str(ds.get("Manufacturer", ""))[:64],
                      "geometry_from": "ultrasound region" if crop is not None else
                      "PixelSpacing" if spacing is not None else "none"}}


def _header(src: str, notes: list[str]):
    """The file's data set without its pixels, every element converted (see
    :func:`_readable`); a RecordingError for a file that is not DICOM or holds a volume."""
    import pydicom
    from pydicom.errors import InvalidDicomError

    if not Path(src).is_file():
        raise RecordingError(f"{src}: not a regular file")
    try:
        with _ClampedFile(src) as fh:
            ds = pydicom.dcmread(fh, stop_before_pixels=True)
            _readable(ds, src, notes)
            if getattr(ds, "file_meta", None) is not None:
                _readable(ds.file_meta, src, notes)
    except InvalidDicomError:
        raise RecordingError(f"{src}: not a DICOM file (no DICM signature or file meta "
                             "information)") from None
    except Exception as exc:  # a damaged header: pydicom's own exception types vary
        raise RecordingError(f"{src}: its DICOM header cannot be read "
                             f"({type(exc).__name__}: {str(exc)[:160]})") from None
    sop = str(ds.get("SOPClassUID", ""))
    if sop in _VOLUME_SOPS:
        raise RecordingError(f"{src}: an {_VOLUME_SOPS[sop]} (a 3D volume in DICOM frames); "
                             "needlenet reads DICOM 2D frames and cine loops; export the volume "
                             "as NRRD or a PLUS metafile")
    return ds


def _int(ds, key: str, src: str, default=None):
    v = ds.get(key, default)
    try:
        return int(v)
    except (TypeError, ValueError, OverflowError):
        raise RecordingError(f"{src}: {key} is {str(v)[:40]!r}, not a whole number") from None


def _check_frame_count(n: int, shape, channels: int, bits: int, compressed: bool,
                       src: str) -> None:
    """NumberOfFrames against the file's size: uncompressed frames take their bytes each, a
    compressed one at least a byte (a damaged count of 10^12 is an error, not an index of
    10^12 frames)."""
    size = os.path.getsize(src)
    per_frame = 1 if compressed else -(-shape[0] * shape[1] * channels * bits // 8)
    if n * per_frame > size:
        held = size // per_frame
        raise RecordingError(f"{src}: NumberOfFrames (0028,0008) is {n}, but the file's "
                             f"{size} bytes hold at most {held} frame{'s' * (held != 1)} of "
                             f"{shape[1]}x{shape[0]} pixels")


def _pixel_format(ds, src: str) -> tuple[tuple[int, int], int, int]:
    """(rows, columns), samples per pixel and bits allocated, checked."""
    missing = [k for k in ("Rows", "Columns", "BitsAllocated", "PhotometricInterpretation")
               if k not in ds]
    if missing:
        raise RecordingError(f"{src}: holds no image ({', '.join(missing)} missing: a "
                             "structured report, a DICOMDIR or a presentation state?)")
    rows, cols = _int(ds, "Rows", src), _int(ds, "Columns", src)
    channels = _int(ds, "SamplesPerPixel", src, default=1)
    bits = _int(ds, "BitsAllocated", src)
    if channels not in (1, 3) or bits not in (1, 8, 16, 32):
        raise RecordingError(f"{src}: {channels} samples of {bits} bits per pixel; needlenet "
                             "reads gray or colour images of 8, 16 or 32 bits")
    return (rows, cols), channels, bits


@dataclass
class _Decoder:
    """Frame ``i`` of the file as uint8 gray, decoded by pydicom: uncompressed frames read
    from the file one at a time (a long loop never sits in memory), compressed ones from the
    file's data held in memory once (a tenth of the frames' size; parsing the file again for
    each frame would cost more than decoding it)."""

    src: str
    uid: str  # the transfer syntax
    photometric: str
    bits_stored: int
    signed: bool
    compressed: bool
    header: object = None  # the data set without its pixels (a palette's lookup tables)
    _held: object = None

    @property
    def syntax(self) -> str:
        """The transfer syntax's name (its UID where pydicom does not know it)."""
        from pydicom.uid import UID

        name = UID(self.uid).name
        return name or self.uid

    def read(self, i: int) -> np.ndarray:
        try:
            with _quiet_pydicom():
                arr = self._decode(i)
        except Exception as exc:  # a damaged or truncated frame: pydicom's errors vary
            raise RecordingError(f"{self.src}: frame {i} cannot be decoded "
                                 f"({type(exc).__name__}: {str(exc)[:160]})") from None
        return self._gray(arr)

    def _decode(self, i: int) -> np.ndarray:
        import pydicom
        from pydicom.pixels import pixel_array

        if not self.compressed:
            with _ClampedFile(self.src) as fh:
                return pixel_array(fh, index=i)
        if self._held is None:
            with _ClampedFile(self.src) as fh:
                self._held = pydicom.dcmread(fh)
        if self.uid == _JPEG_BASELINE and self.photometric in _LIBJPEG_PHOTOMETRIC:
            arr = _libjpeg_frame(self._held, i)
            if arr is not None:
                return arr
        return pixel_array(self._held, index=i)

    def _gray(self, arr: np.ndarray) -> np.ndarray:
        if self.photometric == "PALETTE COLOR":  # indices into the file's colour tables
            from pydicom.pixels import apply_color_lut

            arr = apply_color_lut(arr, self.header)
            if arr.dtype != np.uint8:  # 16-bit table entries
                arr = (arr >> 8).astype(np.uint8)
        if arr.ndim == 3:  # RGB (YBR converted by pydicom): the luma of BGR, marks filled
            if arr.dtype != np.uint8:
                arr = _scaled(arr, self.bits_stored, self.signed)
            return _gray(np.ascontiguousarray(arr[..., ::-1]))
        gray = arr if arr.dtype == np.uint8 else _scaled(arr, self.bits_stored, self.signed)
        if self.photometric == "MONOCHROME1":  # the lowest value is white
            gray = 255 - gray
        return np.ascontiguousarray(gray)


_JPEG_BASELINE = "1.2.840.10008.1.2.4.50"
# what a JPEG baseline frame's own colour transform decodes right (JFIF's YCbCr, or gray)
_LIBJPEG_PHOTOMETRIC = ("YBR_FULL_422", "YBR_FULL", "MONOCHROME2")


def _libjpeg_frame(ds, i: int) -> np.ndarray | None:
    """Frame ``i`` of a JPEG baseline data set decoded by OpenCV's libjpeg (RGB, or gray):
    the same pixels as Pillow's decode and pydicom's YBR conversion, in a third of the time;
    None where OpenCV cannot decode it (pydicom then tries, and says why)."""
    import cv2
    from pydicom.encaps import get_frame

    data = get_frame(ds.PixelData, i, number_of_frames=int(ds.get("NumberOfFrames", 1) or 1))
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint8:
        return None
    return img[..., ::-1] if img.ndim == 3 else img  # BGR -> RGB


def _scaled(arr: np.ndarray, bits_stored: int, signed: bool) -> np.ndarray:
    """Stored values of ``bits_stored`` bits to 0..255, their full range to the full range."""
    a = arr.astype(np.float64)
    top = float(2 ** bits_stored - 1)
    if signed:
        a = a + 2.0 ** (bits_stored - 1)
    return np.rint(np.clip(a, 0.0, top) * (255.0 / top)).astype(np.uint8)


def _decoder(ds, src: str) -> _Decoder:
    from pydicom.pixels import get_decoder

    meta = getattr(ds, "file_meta", None)
    syntax = meta.get("TransferSyntaxUID") if meta is not None else None
    if syntax is None:
        raise RecordingError(f"{src}: no TransferSyntaxUID (0002,0010) in its file meta "
                             "information")
    try:
        dec = get_decoder(syntax)
        ok = dec.is_available
    except Exception:
        dec, ok = None, False
    if not ok:
        name = getattr(syntax, "name", str(syntax))
        raise RecordingError(
            f"{src}: pixel data compressed as {name} ({syntax}), which needlenet cannot decode "
            "(it reads uncompressed, RLE, JPEG baseline and extended, and JPEG 2000 files); "
            "convert it first, e.g. `gdcmconv --raw IN.dcm OUT.dcm` or `dcmdjpeg IN OUT`")
    bits_stored = _int(ds, "BitsStored", src, default=_int(ds, "BitsAllocated", src))
    if not 1 <= bits_stored <= 32:
        raise RecordingError(f"{src}: BitsStored (0028,0101) is {bits_stored}")
    compressed = bool(getattr(syntax, "is_compressed", False))
    if compressed:
        check_allocation((os.path.getsize(src),), 1, src, "its compressed pixel data")
    return _Decoder(src, str(syntax), str(ds.get("PhotometricInterpretation", "")),
                    bits_stored, _int(ds, "PixelRepresentation", src, default=0) == 1,
                    compressed, ds)


def _geometry(ds, src: str, shape: tuple[int, int]):
    """(spacing_mm, origin_mm of the whole frame, crop, a note or ''): from the tissue region
    of the Sequence of Ultrasound Regions, else from PixelSpacing (no origin, no crop)."""
    regions = []
    for k, r in enumerate(ds.get("SequenceOfUltrasoundRegions", []) or []):
        try:
            fmt = int(r.get("RegionSpatialFormat", -1))
            kind = int(r.get("RegionDataType", -1))
            units = (int(r.get("PhysicalUnitsXDirection", -1)),
                     int(r.get("PhysicalUnitsYDirection", -1)))
            dx, dz = float(r.PhysicalDeltaX), float(r.PhysicalDeltaY)
            box = [int(r.RegionLocationMinX0), int(r.RegionLocationMinY0),
                   int(r.RegionLocationMaxX1), int(r.RegionLocationMaxY1)]
        except (AttributeError, TypeError, ValueError, OverflowError):
            continue  # a region without its calibration: not one to measure in
        if fmt != _SPATIAL_2D or units != (_CM, _CM) or not (dx and dz) or \
                not (np.isfinite(dx) and np.isfinite(dz)):
            continue
        x0, y0, x1, y1 = box
        if not (0 <= x0 < x1 < shape[1] and 0 <= y0 < y1 < shape[0]):
            raise RecordingError(
                f"{src}: ultrasound region {k} spans columns {x0}-{x1} and rows {y0}-{y1}, "
                f"outside the {shape[1]}x{shape[0]} image (SequenceOfUltrasoundRegions)")
        regions.append((kind == _TISSUE, (x1 - x0 + 1) * (y1 - y0 + 1), k, r, dx, dz, box))
    if regions:
        regions.sort(key=lambda t: (t[0], t[1]), reverse=True)
        tissue, _, k, r, dx, dz, (x0, y0, x1, y1) = regions[0]
        spacing = np.array([abs(dz), abs(dx)]) * 10.0
        crop = (x0, y0, x1 - x0 + 1, y1 - y0 + 1)
        # physical position of the region's pixel (0, 0), then of the frame's
        ref = [r.get(k_) for k_ in ("ReferencePixelX0", "ReferencePixelY0",
                                    "ReferencePixelPhysicalValueX",
                                    "ReferencePixelPhysicalValueY")]
        region_x0, region_z0 = 0.0, 0.0  # without a reference pixel: the region's corner
        try:
            if all(v is not None for v in ref):
                rx, ry, px, py = (float(v) for v in ref)
                region_x0, region_z0 = (px - rx * dx) * 10.0, (py - ry * dz) * 10.0
        except (TypeError, ValueError, OverflowError):
            pass
        origin = np.array([region_z0 - y0 * spacing[0], region_x0 - x0 * spacing[1]])
        note = ""
        if len(regions) > 1:
            note = (f"{src}: {len(regions)} calibrated image regions; tracking region {k} "
                    f"({crop[2]}x{crop[3]} pixels at {x0},{y0}), the largest "
                    f"{'tissue ' if tissue else ''}image (--crop chooses another)")
        return spacing, origin, crop, note
    ps = ds.get("PixelSpacing")
    if ps is not None:
        try:
            spacing = np.array([float(ps[0]), float(ps[1])])
        except (TypeError, ValueError, IndexError):
            raise RecordingError(f"{src}: PixelSpacing (0028,0030) is {str(ps)[:40]!r}, not "
                                 "two numbers") from None
        return spacing, None, None, ""
    return None, None, None, ""


def _frame_times(ds, n: int, src: str) -> np.ndarray | None:
    """Frame times (s) from the file, or None when it gives none (one frame: [0])."""
    if n == 1:
        return np.zeros(1)
    vec = ds.get("FrameTimeVector")
    if vec is not None:
        try:
            inc = np.asarray([float(v) for v in vec], float)
        except (TypeError, ValueError):
            raise RecordingError(f"{src}: FrameTimeVector (0018,1065) holds values that are "
                                 "not numbers") from None
        if inc.size != n:
            raise RecordingError(f"{src}: FrameTimeVector (0018,1065) has {inc.size} values "
                                 f"for {n} frames")
        inc[0] = 0.0  # the first entry is the time from a frame before the first: 0
        return np.cumsum(inc) / 1000.0
    for key, per_frame_s in (("FrameTime", lambda v: v / 1000.0),
                             ("CineRate", lambda v: 1.0 / v),
                             ("RecommendedDisplayFrameRate", lambda v: 1.0 / v)):
        v = ds.get(key)
        if v is None:
            continue
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise RecordingError(f"{src}: {key} is {str(v)[:40]!r}, not a number") from None
        if not (np.isfinite(v) and v > 0):
            raise RecordingError(f"{src}: {key} is {v}; it must be positive")
        return np.arange(n) * per_frame_s(v)
    return None
