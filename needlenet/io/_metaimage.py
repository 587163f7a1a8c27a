"""PLUS sequence metafiles: ``.mha`` / ``.seq.mha`` / ``.igs.mha`` and ``.mhd`` + ``.raw``.

The format is MetaIO's (ITK's MetaImage): a text header of ``Key = Value`` lines ending with
``ElementDataFile``, then the pixels, x fastest. PLUS (the Public software Library for
UltraSound, "Sequence file" in its user manual) adds, for a sequence of 2D frames:

- ``NDims = 3``, ``DimSize = W H T``, ``Kinds = domain domain list`` (a volume sequence:
  ``NDims = 4``, ``DimSize = W H D T``, ``Kinds = domain domain domain list``). ``NDims = 3``
  without ``Kinds`` is read as 2D frames, as PLUS means it; with ``Kinds = domain domain
  domain`` as one volume; ``NDims = 2`` as one frame;
- ``ElementType`` (``MET_UCHAR`` for B-mode), ``ElementNumberOfChannels``,
  ``ElementSpacing`` (mm per pixel along x, y(, z), then 1 for the frame axis), ``Offset``,
  ``TransformMatrix``, ``BinaryDataByteOrderMSB`` / ``ElementByteOrderMSB``;
- ``CompressedData = True`` with ``CompressedDataSize`` (one zlib stream of every frame);
- ``ElementDataFile = LOCAL`` (the pixels follow the header) or the name of a ``.raw`` /
  ``.zraw`` file next to an ``.mhd`` header (``HeaderSize`` bytes skipped in it; -1: the
  pixels are the file's last bytes);
- ``UltrasoundImageOrientation`` (``MF``, ``MN``, ``UF``, ``UN``, and a third letter ``A``/``D``
  for volumes) and ``UltrasoundImageType`` (``BRIGHTNESS`` for B-mode);
- per frame, ``Seq_FrameNNNN_<Name>Transform`` (16 numbers, a row-major 4x4 matrix),
  ``Seq_FrameNNNN_<Name>TransformStatus`` (``OK`` or ``INVALID``),
  ``Seq_FrameNNNN_Timestamp`` (seconds), ``Seq_FrameNNNN_ImageStatus`` (``OK`` or
  ``INVALID``) and any other ``Seq_FrameNNNN_<Field>`` custom frame field.

**Orientation.** PLUS names the direction of the image's first (column, x) axis by the side of
the transducer it points from, ``M`` (the marked side) or ``U`` (unmarked), and that of its
second (row, y) axis by ``F`` (going far from the transducer: depth increasing down the rows)
or ``N`` (near). The canonical ``MF`` is read as is: columns are lateral from the marked side
and rows are depth, the sequence file's ``[depth, lateral]``. ``U`` flips the lateral axis,
``N`` flips the depth axis, and for volumes ``D`` (descending) flips the third, elevation, axis
(``A``, ascending, keeps it). needlenet always writes ``MF`` (``MFA`` for volumes).

**Volumes.** PLUS stores x lateral, y depth, z elevation; the sequence file's array order is
``[depth, elevation, lateral]``, so volume frames are transposed on reading and back on
writing, and ``ElementSpacing = sx sy sz`` becomes ``spacing_mm = (sy, sz, sx)``.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._atomic import atomic_write
from ._errors import RecordingError
from ._gray import to_gray_uint8
from ._lazy import ZlibStream, inflated_frames, is_frame_stack, mapped_frames
from ._limits import check_allocation, check_frame_shape
from ._plus_data import (
    check_inflated,
    compressed_span,
    first_frame,
    header_numbers,
    pixel_bytes,
    raw_span,
)

__all__ = ["PlusSequence", "read_plus", "write_plus", "plus_outputs", "ORIENTATIONS",
           "PLUS_SUFFIXES"]

PLUS_SUFFIXES = (".mha", ".mhd")
ORIENTATIONS = ("MF", "MN", "UF", "UN")

_ELEMENT_TYPES = {
    "MET_UCHAR": "u1", "MET_CHAR": "i1", "MET_USHORT": "u2", "MET_SHORT": "i2",
    "MET_UINT": "u4", "MET_INT": "i4", "MET_ULONG_LONG": "u8", "MET_LONG_LONG": "i8",
    "MET_FLOAT": "f4", "MET_DOUBLE": "f8",
}
_FRAME_FIELD = re.compile(r"^Seq_Frame(\d+)_(\w+)$")
_MAX_LINE = 1 << 22  # a header line longer than this is not a header


@dataclass
class PlusSequence:
    """The content of a PLUS sequence metafile, in the sequence file's conventions.

    ``images`` are uint8 ``(T, H, W)`` ([depth, lateral]) or ``(T, Z, Y, X)`` ([depth,
    elevation, lateral]) after ``UltrasoundImageOrientation`` has been applied;
    ``spacing_mm`` / ``origin_mm`` are in that array order (``spacing_mm`` is None when the
    header has no ``ElementSpacing``). ``transforms`` maps a name such as
    ``"ProbeToReference"`` (the field name without ``Transform``) to ``(T, 4, 4)`` matrices and
    ``transform_ok`` to ``(T,)`` booleans (``TransformStatus == OK``; a frame without the field
    is INVALID with an identity matrix). ``frame_fields`` holds the other per-frame fields as
    strings (None where a frame lacks one); ``fields`` the other header fields.
    """

    images: np.ndarray
    spacing_mm: np.ndarray | None = None
    origin_mm: np.ndarray | None = None
    timestamps_s: np.ndarray | None = None
    transforms: dict[str, np.ndarray] = field(default_factory=dict)
    transform_ok: dict[str, np.ndarray] = field(default_factory=dict)
    image_ok: np.ndarray | None = None
    frame_fields: dict[str, list] = field(default_factory=dict)
    fields: dict[str, str] = field(default_factory=dict)
    orientation: str = "MF"
    intensity_range: tuple[float, float] | None = None  # set when non-uint8 pixels were scaled
    notes: list[str] = field(default_factory=list)  # what reading changed, for the user

    @property
    def n_frames(self) -> int:
        return int(self.images.shape[0])


# -- reading ---------------------------------------------------------------------------------

def _read_header(fh, src: str) -> tuple[dict[str, str], int]:
    """``Key = Value`` lines up to and including ``ElementDataFile``; the data offset."""
    header: dict[str, str] = {}
    n = 0
    while True:
        raw = fh.readline(_MAX_LINE)
        n += 1
        if not raw:
            if not header:
                raise RecordingError(f"{src}: empty file, not a MetaImage (.mha/.mhd) header")
            raise RecordingError(f"{src}: truncated header: no ElementDataFile line after "
                                 f"{n - 1} lines")
        if len(raw) >= _MAX_LINE and not raw.endswith(b"\n"):
            raise RecordingError(f"{src}: header line {n} is longer than {_MAX_LINE} bytes; "
                                 "not a MetaImage header")
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            raise RecordingError(f"{src}: header line {n} is not text; not a MetaImage "
                                 "(.mha/.mhd) file, or its header is damaged") from None
        if not line:
            continue
        if "=" not in line:
            raise RecordingError(f"{src}: header line {n} ({line[:40]!r}) is not 'Key = Value'")
        key, value = (s.strip() for s in line.split("=", 1))
        if n == 1 and key not in ("ObjectType", "NDims"):
            raise RecordingError(f"{src}: not a MetaImage header (first field {key!r}, "
                                 "expected ObjectType or NDims)")
        if key in header:
            raise RecordingError(f"{src}: header field {key} appears twice")
        header[key] = value
        if key == "ElementDataFile":
            return header, fh.tell()


def _flag(header: dict, key: str, src: str) -> bool:
    v = header.get(key, "False").strip().lower()
    if v not in ("true", "false", "1", "0"):
        raise RecordingError(f"{src}: field {key} = {header[key]!r} must be True or False")
    return v in ("true", "1")


def _orient(images: np.ndarray, code: str, volume: bool, src: str) -> np.ndarray:
    c = code.strip().upper()
    if len(c) not in (2, 3) or c[:2] not in ORIENTATIONS or (len(c) == 3 and c[2] not in "AD"):
        raise RecordingError(
            f"{src}: UltrasoundImageOrientation = {code!r} is unknown; expected one of "
            f"{', '.join(ORIENTATIONS)} (optionally with A or D for volumes)")
    if c[0] == "U":
        images = images[..., ::-1]  # x: the lateral axis
    if c[1] == "N":
        images = images[..., ::-1, :]  # y: the depth axis
    if volume and len(c) == 3 and c[2] == "D":
        images = images[:, ::-1]  # z: the elevation axis
    return images


def read_plus(path: str | os.PathLike) -> PlusSequence:
    """Read a PLUS sequence metafile (``.mha`` with the pixels inside, or ``.mhd`` and its
    ``.raw``), compressed or not; raise :class:`RecordingError` naming the file and field."""
    path = Path(path)
    src = str(path)
    if not path.is_file():
        raise FileNotFoundError(f"{src}: no such recording")
    with open(path, "rb") as fh:
        header, offset = _read_header(fh, src)
    if header.get("ObjectType", "Image") != "Image":
        raise RecordingError(f"{src}: ObjectType = {header['ObjectType']!r}; expected Image")
    for key in ("NDims", "DimSize", "ElementType"):
        if key not in header:
            raise RecordingError(f"{src}: header field {key} is missing")
    ndims = int(header_numbers(header, "NDims", src, 1, int)[0])
    if ndims not in (2, 3, 4):
        raise RecordingError(f"{src}: NDims = {ndims}; expected 2 (one image), 3 (a sequence "
                             "of 2D frames or one volume) or 4 (a sequence of volumes)")
    dims = header_numbers(header, "DimSize", src, ndims, int)
    if np.any(dims < 1):
        raise RecordingError(f"{src}: DimSize = {header['DimSize']} must be positive")
    kinds = header.get("Kinds", "").split()
    if kinds and len(kinds) != ndims:
        raise RecordingError(f"{src}: Kinds has {len(kinds)} entries for NDims = {ndims}")
    is_list = bool(kinds) and kinds[-1] == "list"
    if ndims == 2:
        volume, dims_sp, T = False, dims, 1
    elif ndims == 3:
        volume = bool(kinds) and not is_list  # Kinds = domain domain domain: one volume
        dims_sp, T = (dims, 1) if volume else (dims[:2], int(dims[2]))
    else:
        volume, dims_sp, T = True, dims[:3], int(dims[3])
    etype = header["ElementType"]
    if etype not in _ELEMENT_TYPES:
        raise RecordingError(f"{src}: ElementType = {etype!r} is not supported; use one of "
                             f"{', '.join(_ELEMENT_TYPES)}")
    dtype = np.dtype(_ELEMENT_TYPES[etype])
    msb = _flag(header, "ElementByteOrderMSB", src) or _flag(header, "BinaryDataByteOrderMSB",
                                                             src)
    if dtype.itemsize > 1:
        dtype = dtype.newbyteorder(">" if msb else "<")
    channels = int(header_numbers(header, "ElementNumberOfChannels", src, 1, int)[0]) \
        if "ElementNumberOfChannels" in header else 1
    if channels < 1 or channels > 4:
        raise RecordingError(f"{src}: ElementNumberOfChannels = {channels}; expected 1 to 4")
    if not _flag(header, "BinaryData", src) and "BinaryData" in header:
        raise RecordingError(f"{src}: BinaryData = False (pixels as text) is not supported")
    compressed = _flag(header, "CompressedData", src)
    shape = (T, *[int(d) for d in dims_sp[::-1]]) + ((channels,) if channels > 1 else ())
    # 8-bit pixels are read frame by frame, through a memory map or inflated in order (gray
    # and orientation are per pixel); other types need the whole recording's intensity range
    span = None
    if not compressed and dtype == np.uint8:
        span = raw_span(path, src, header, offset, math.prod(shape))
    if span is None:
        nbytes = check_allocation(shape, dtype.itemsize, src, "DimSize/ElementType")
    check_frame_shape(shape[1:1 + len(dims_sp)], src, "DimSize")
    code = header.get("UltrasoundImageOrientation", "MF")

    def prepare(arr: np.ndarray) -> tuple[np.ndarray, tuple | None, list]:
        """(T, *file frame) pixels -> uint8 frames in array order, the scaled intensity
        range and the notes (see :func:`~._gray.to_gray_uint8`)."""
        images, irange, notes = to_gray_uint8(arr, channels)
        images = _orient(images, code, volume, src)
        if volume:
            images = images.transpose(0, 2, 1, 3)  # (T, z, y, x) -> [depth, elevation, lateral]
        return images, irange, notes

    stream = None
    if span is not None:
        raw = first_frame(span, shape, dtype)  # the others are read when asked for
    elif compressed and dtype == np.uint8:  # inflated frame by frame when read
        target, start, length = compressed_span(path, src, header, offset, nbytes)
        stream = ZlibStream(target, start, length)
        check_inflated(stream, nbytes, str(target))
        frame_bytes = math.prod(shape[1:])
        raw = np.frombuffer(stream.next_bytes(frame_bytes), dtype).reshape((1, *shape[1:]))
    else:
        blob = pixel_bytes(path, src, header, offset, nbytes, compressed)
        raw = np.frombuffer(blob, dtype=dtype).reshape(shape)

    frames: dict[str, list] = {}
    for key, value in header.items():
        m = _FRAME_FIELD.match(key)
        if not m:
            continue
        i, name = int(m.group(1)), m.group(2)
        if i >= T:
            raise RecordingError(f"{src}: field {key}: frame {i} is beyond DimSize's {T} frames")
        frames.setdefault(name, [None] * T)[i] = value

    images, irange, notes = prepare(raw)
    if span is not None:
        images = mapped_frames(span[0], span[1], T, shape[1:], dtype,
                               lambda f: prepare(f[None])[0][0], images.shape[1:])
    elif stream is not None:
        images = inflated_frames(stream, T, shape[1:], dtype, lambda f: prepare(f[None])[0][0],
                                 images.shape[1:], src)
    else:
        images = np.ascontiguousarray(images)
        if not images.flags.writeable:  # a view of the bytes read: give the caller its own
            images = images.copy()
    utype = header.get("UltrasoundImageType", "BRIGHTNESS").upper()
    if utype not in ("BRIGHTNESS", "UNKNOWN", ""):
        raise RecordingError(f"{src}: UltrasoundImageType = {utype}; needlenet tracks B-mode "
                             "(BRIGHTNESS) frames")

    nsp = 3 if volume else 2
    perm = [1, 2, 0] if volume else [1, 0]  # file (x, y, z) -> array (y, z, x) or (y, x)
    spacing = origin = None
    if "ElementSpacing" in header:
        sp = header_numbers(header, "ElementSpacing", src, ndims)[:nsp]
        if np.any(sp <= 0):
            raise RecordingError(f"{src}: ElementSpacing = {header['ElementSpacing']} must be "
                                 "positive")
        spacing = sp[perm]
    off = header.get("Offset", header.get("Position", header.get("Origin")))
    if off is not None:
        key = next(k for k in ("Offset", "Position", "Origin") if k in header)
        origin = header_numbers(header, key, src, ndims)[:nsp][perm]

    transforms, ok = {}, {}
    timestamps = None
    image_ok = np.ones(T, bool)
    frame_fields = {}
    for name, values in frames.items():
        if name.endswith("TransformStatus"):
            continue
        if name.endswith("Transform"):
            mats = np.repeat(np.eye(4)[None], T, axis=0)
            status = frames.get(name + "Status", [None] * T)
            good = np.zeros(T, bool)
            for i, v in enumerate(values):
                if v is None:
                    continue
                try:
                    m = np.array([float(s) for s in v.split()])
                except ValueError:
                    m = np.empty(0)
                if m.size != 16 or not np.all(np.isfinite(m)):
                    raise RecordingError(f"{src}: field Seq_Frame{i:04d}_{name} must be 16 "
                                         f"finite numbers (a row-major 4x4), got {v[:60]!r}")
                mats[i] = m.reshape(4, 4)
                s = status[i]
                good[i] = s is None or s.strip().upper() == "OK"
            stem = name[:-len("Transform")]
            transforms[stem], ok[stem] = mats, good
        elif name == "Timestamp":
            if all(v is not None for v in values):
                try:
                    timestamps = np.array([float(v) for v in values])
                except ValueError:
                    raise RecordingError(f"{src}: a Seq_FrameNNNN_Timestamp field is not a "
                                         "number") from None
        elif name == "ImageStatus":
            image_ok = np.array([v is None or v.strip().upper() == "OK" for v in values])
        else:
            frame_fields[name] = values
    other = {k: v for k, v in header.items() if not _FRAME_FIELD.match(k)}
    return PlusSequence(images=images, spacing_mm=spacing, origin_mm=origin,
                        timestamps_s=timestamps, transforms=transforms, transform_ok=ok,
                        image_ok=image_ok, frame_fields=frame_fields, fields=other,
                        orientation=code.strip().upper(), intensity_range=irange,
                        notes=[f"{src}: {n}" for n in notes])


# -- writing ---------------------------------------------------------------------------------

def _num(v) -> str:
    f = float(v)
    return str(int(f)) if f.is_integer() and abs(f) < 1e15 else repr(f)


def _nums(vals) -> str:
    return " ".join(_num(v) for v in np.asarray(vals, float).ravel())


def plus_outputs(path: str | os.PathLike, compress: bool = True) -> list[Path]:
    """The files :func:`write_plus` writes for ``path``: the ``.mha``, or the ``.mhd`` and its
    ``.raw`` (``.zraw`` when compressed)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in PLUS_SUFFIXES:
        raise RecordingError(f"output {path}: a PLUS sequence file must end in .mha or .mhd "
                             "(e.g. NAME.seq.mha)")
    if suffix == ".mha":
        return [path]
    return [path, path.with_suffix(".zraw" if compress else ".raw")]


def write_plus(path: str | os.PathLike, plus: PlusSequence, *, compress: bool = True,
               overwrite: bool = False, extra_fields: dict[str, str] | None = None
               ) -> list[Path]:
    """Write ``plus`` as a PLUS sequence metafile (``UltrasoundImageOrientation = MF``).

    ``.mha``: one file; ``.mhd``: a header and a ``.raw``/``.zraw``. Written to temporary
    files and renamed, so nothing partial replaces an existing output; an existing output is
    refused unless ``overwrite``. ``extra_fields`` are written as header fields."""
    outputs = plus_outputs(path, compress)
    images = plus.images if is_frame_stack(plus.images) else np.asarray(plus.images)
    src = str(outputs[0])
    if images.dtype != np.uint8 or images.ndim not in (3, 4):
        raise RecordingError(f"output {src}: images must be uint8 (T, H, W) or (T, Z, Y, X), "
                             f"got {images.dtype} {images.shape}")
    if plus.spacing_mm is None:
        raise RecordingError(f"output {src}: spacing_mm is required")
    T = images.shape[0]
    volume = images.ndim == 4
    spacing = np.asarray(plus.spacing_mm, float)
    origin = np.zeros(images.ndim - 1) if plus.origin_mm is None else \
        np.asarray(plus.origin_mm, float)
    if volume:
        sp, org = spacing[[2, 0, 1]], origin[[2, 0, 1]]
        dims = (images.shape[3], images.shape[1], images.shape[2], T)
    else:
        sp, org = spacing[[1, 0]], origin[[1, 0]]
        dims = (images.shape[2], images.shape[1], T)
    nd = len(dims)
    blob_size, write_blob = _pixel_data(images, volume, compress)
    lines = [("ObjectType", "Image"), ("NDims", str(nd))]
    if nd == 3:
        lines.append(("AnatomicalOrientation", "RAI"))
    lines += [("BinaryData", "True"), ("BinaryDataByteOrderMSB", "False"),
              ("CenterOfRotation", " ".join(["0"] * nd)),
              ("CompressedData", "True" if compress else "False")]
    if compress:
        lines.append(("CompressedDataSize", str(blob_size)))
    lines += [("DimSize", " ".join(str(int(d)) for d in dims)),
              ("ElementNumberOfChannels", "1"),
              ("ElementSpacing", _nums([*sp, 1.0])),
              ("ElementType", "MET_UCHAR"),
              ("Kinds", " ".join(["domain"] * (nd - 1) + ["list"])),
              ("Offset", _nums([*org, 0.0])),
              ("TransformMatrix", _nums(np.eye(nd))),
              ("UltrasoundImageOrientation", "MFA" if volume else "MF"),
              ("UltrasoundImageType", "BRIGHTNESS")]
    for k, v in (extra_fields or {}).items():
        if "\n" in str(v) or "=" in k or _FRAME_FIELD.match(k):
            raise RecordingError(f"output {src}: header field {k!r} must be one line")
        lines.append((k, str(v)))
    ts = None if plus.timestamps_s is None else np.asarray(plus.timestamps_s, float)
    if ts is not None and ts.shape != (T,):
        raise RecordingError(f"output {src}: {ts.shape} timestamps for {T} frames")
    for name, mats in plus.transforms.items():
        if np.asarray(mats).shape != (T, 4, 4):
            raise RecordingError(f"output {src}: transform {name} must be ({T}, 4, 4)")
    image_ok = np.ones(T, bool) if plus.image_ok is None else np.asarray(plus.image_ok, bool)
    for i in range(T):
        f = f"Seq_Frame{i:04d}_"
        for name, mats in plus.transforms.items():
            good = plus.transform_ok.get(name)
            good_i = True if good is None else bool(good[i])
            m = np.asarray(mats[i], float) if good_i else np.eye(4)
            lines.append((f"{f}{name}Transform", _nums(m)))
            lines.append((f"{f}{name}TransformStatus", "OK" if good_i else "INVALID"))
        for name, values in plus.frame_fields.items():
            if values[i] is not None:
                lines.append((f"{f}{name}", str(values[i])))
        if ts is not None:
            lines.append((f"{f}Timestamp", repr(float(ts[i]))))
        lines.append((f"{f}ImageStatus", "OK" if image_ok[i] else "INVALID"))
    data_name = "LOCAL" if len(outputs) == 1 else outputs[1].name
    lines.append(("ElementDataFile", data_name))
    head = "".join(f"{k} = {v}\n" for k, v in lines).encode("utf-8")
    if len(outputs) == 1:
        writers = {outputs[0]: lambda fh: (fh.write(head), write_blob(fh))}
    else:
        writers = {outputs[1]: write_blob, outputs[0]: lambda fh: fh.write(head)}
    atomic_write(writers, overwrite)
    return outputs


def _pixel_data(images, volume: bool, compress: bool):
    """The pixels as the file holds them ((T, z, y, x) for volumes), as (their size in bytes,
    ``write(fh)``). An array is written as one byte string (zlib level 1 when compressed); a
    :class:`~._lazy.FrameStack` frame by frame, its zlib stream first made in an unnamed
    temporary file (the header gives its size), so that a long recording is never whole in
    memory."""
    if not is_frame_stack(images):
        data = np.ascontiguousarray(images.transpose(0, 2, 1, 3) if volume else images)
        raw = data.tobytes()
        blob = zlib.compress(raw, 1) if compress else raw
        return len(blob), lambda fh: fh.write(blob)

    def frames():
        for k in range(len(images)):
            f = images[k]
            yield np.ascontiguousarray(f.transpose(1, 0, 2) if volume else f).tobytes()

    if not compress:
        def write_frames(fh):
            for b in frames():
                fh.write(b)

        return images.nbytes, write_frames
    spool = tempfile.TemporaryFile()
    z = zlib.compressobj(1)
    for b in frames():
        spool.write(z.compress(b))
    spool.write(z.flush())

    def write(fh):
        spool.seek(0)
        shutil.copyfileobj(spool, fh)
        spool.close()

    return spool.tell(), write
