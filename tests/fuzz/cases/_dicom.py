"""DICOM cine loops with damaged attributes and bytes: the image pixel module (rows, columns,
frames, bits, samples, photometric), the transfer syntax, frame times, pixel spacing and the
ultrasound regions' calibration (units, deltas, bounds, reference pixel)."""

from __future__ import annotations

import io
import logging
import warnings

import numpy as np

from ._base import Base, _case, _track, mutate_bytes, pick

DICOM_INPUTS = ("i.dcm", "ic.dcm", "ir.dcm", "IM_0001", "series")
SERIES = tuple(f"series/IM_{k:04d}" for k in range(1, 6))

_VALUES = (0, -1, 1, 3, 7, 255, 65535, 2 ** 31 - 1, 1e-12, 1e12, float("nan"),
           float("inf"), -0.5, "x", "", "1\\2\\3")
_PIXEL = ("Rows", "Columns", "NumberOfFrames", "BitsAllocated", "BitsStored", "HighBit",
          "SamplesPerPixel", "PhotometricInterpretation", "PixelRepresentation",
          "PlanarConfiguration")
_TIMES = ("FrameTime", "FrameTimeVector", "CineRate", "PixelSpacing")
_REGION = ("PhysicalDeltaX", "PhysicalDeltaY", "PhysicalUnitsXDirection",
           "PhysicalUnitsYDirection", "RegionLocationMinX0", "RegionLocationMinY0",
           "RegionLocationMaxX1", "RegionLocationMaxY1", "RegionSpatialFormat",
           "RegionDataType", "ReferencePixelX0", "ReferencePixelY0",
           "ReferencePixelPhysicalValueX", "ReferencePixelPhysicalValueY")
_SYNTAXES = ("1.2.840.10008.1.2.4.80", "1.2.840.10008.1.2.4.70", "1.2.840.10008.1.2.5",
             "1.2.840.10008.1.2.4.50", "1.2.840.10008.1.2", "1.2.840.10008.1.2.2",
             "1.2.3.4", "")


def dicom_inputs(seq, root) -> dict[str, bytes]:
    """The valid DICOM inputs from sequence ``seq``: a gray loop on a screen with its
    calibrated region (``i.dcm``, and the same named like a scanner's export), a colour JPEG
    loop (``ic.dcm``), an RLE loop with PixelSpacing (``ir.dcm``)."""
    from tests.dicom_files import region, write_dicom

    im = np.asarray(seq.images)
    T, H, W = im.shape
    scr = np.zeros((T, H + 30, W + 40), np.uint8)
    scr[:, 20:20 + H, 30:30 + W] = im
    reg = [region(30, 20, 29 + W, 19 + H, *seq.spacing_mm, reference=(0, 0, 0.0, 0.0))]
    f = {"i.dcm": write_dicom(root / "i.dcm", scr, regions=reg).read_bytes()}
    f["IM_0001"] = f["i.dcm"]
    f["ic.dcm"] = write_dicom(root / "ic.dcm", np.repeat(scr[..., None], 3, axis=-1),
                              regions=reg, compression="jpeg").read_bytes()
    f["ir.dcm"] = write_dicom(root / "ir.dcm", im, pixel_spacing=list(seq.spacing_mm),
                              compression="rle").read_bytes()
    (root / "series").mkdir(exist_ok=True)
    for k, name in enumerate(SERIES):  # one clip as single-frame files, an export folder's
        f[name] = write_dicom(root / name, im[k:k + 1], pixel_spacing=list(seq.spacing_mm),
                              frame_time_ms=None, attributes={
                                  "InstanceNumber": k + 1, "SeriesInstanceUID": "1.2.3",
                                  "AcquisitionTime": f"1000{k * 0.05:09.6f}"}).read_bytes()
    return f


def _edit(data: bytes, rng) -> tuple[bytes, str]:
    """One attribute of the file set to a bad value or removed (pydicom writes it, without
    its warnings about the values it is made to write)."""
    logger = logging.getLogger("pydicom")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _edit_quietly(data, rng)
    finally:
        logger.setLevel(level)


def _edit_quietly(data: bytes, rng) -> tuple[bytes, str]:
    import pydicom

    ds = pydicom.dcmread(io.BytesIO(data))
    group = pick(rng, ("pixel", "pixel", "times", "region", "region", "syntax"))
    if group == "syntax":
        uid = pick(rng, _SYNTAXES)
        return _with_syntax(data, uid), f"TransferSyntaxUID {uid!r}"
    else:
        names = {"pixel": _PIXEL, "times": _TIMES, "region": _REGION}[group]
        name = pick(rng, names)
        target = ds
        if group == "region":
            if "SequenceOfUltrasoundRegions" not in ds:
                return _edit_quietly(data, rng)
            target = ds.SequenceOfUltrasoundRegions[0]
        value = pick(rng, _VALUES) if rng.random() < 0.8 else None
        try:
            if value is None:
                if name in target:
                    del target[name]
                what = f"{name} removed"
            else:
                setattr(target, name, value)
                what = f"{name} = {value!r}"
            out = io.BytesIO()
            ds.save_as(out, enforce_file_format=True)
            return out.getvalue(), what
        except Exception:  # a value the attribute's VR cannot hold: remove it instead
            ds = pydicom.dcmread(io.BytesIO(data))
            target = ds.SequenceOfUltrasoundRegions[0] if group == "region" else ds
            if name in target:
                del target[name]
            what = f"{name} removed"
    out = io.BytesIO()
    ds.save_as(out, enforce_file_format=True)
    return out.getvalue(), what


def _with_syntax(data: bytes, uid: str) -> bytes:
    """The file with its file meta information rewritten to name transfer syntax ``uid``,
    the data set after it unchanged (pydicom would not write pixels under a syntax that does
    not fit them)."""
    import pydicom
    from pydicom.filebase import DicomBytesIO
    from pydicom.filewriter import write_file_meta_info

    meta = pydicom.dcmread(io.BytesIO(data), stop_before_pixels=True).file_meta
    meta.TransferSyntaxUID = uid
    group_length = int.from_bytes(data[140:144], "little")  # (0002,0000) after DICM
    buf = DicomBytesIO()
    buf.is_little_endian, buf.is_implicit_VR = True, False
    write_file_meta_info(buf, meta, enforce_standard=False)
    return data[:132] + buf.getvalue() + data[132 + 12 + group_length:]


def fam_dicom(rng, base: Base) -> dict:
    inp = pick(rng, DICOM_INPUTS)
    files = base.input_files(inp)
    target = pick(rng, SERIES) if inp == "series" else inp
    data = files[target]
    if rng.random() < 0.6:
        files[target], what = _edit(data, rng)
    else:
        j = data.find(b"\xe0\x7f\x10\x00")  # the Pixel Data tag: header before, pixels after
        lo, hi, where = (0, j, "header") if j > 0 and rng.random() < 0.5 else \
            (max(j, 0), len(data), "pixel data")
        files[target], what = mutate_bytes(data, rng, lo, hi)
        what = f"{what} ({where})"
    return _case("dicom", f"{target}: {what}", _track(inp, rng), files)
