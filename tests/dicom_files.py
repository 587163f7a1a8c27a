"""DICOM ultrasound files for the tests, written with pydicom (and OpenCV's JPEG encoder for
compressed loops) the way scanners export a cine loop: a multi-frame US image with its
Sequence of Ultrasound Regions, frame time and, for colour, YBR JPEG frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

US_MULTIFRAME = "1.2.840.10008.5.1.4.1.1.3.1"


def region(x0: int, y0: int, x1: int, y1: int, dz_mm: float, dx_mm: float,
           reference=None, data_type: int = 1, units: int = 3):
    """A Sequence of Ultrasound Regions item: the box (inclusive pixel bounds), mm per pixel
    (written in cm), ``reference`` = (pixel x, pixel y, physical x cm, physical y cm)."""
    from pydicom.dataset import Dataset

    r = Dataset()
    r.RegionSpatialFormat, r.RegionDataType, r.RegionFlags = 1, data_type, 0
    r.RegionLocationMinX0, r.RegionLocationMinY0 = x0, y0
    r.RegionLocationMaxX1, r.RegionLocationMaxY1 = x1, y1
    r.PhysicalUnitsXDirection = r.PhysicalUnitsYDirection = units
    r.PhysicalDeltaX, r.PhysicalDeltaY = dx_mm / 10.0, dz_mm / 10.0
    if reference is not None:
        (r.ReferencePixelX0, r.ReferencePixelY0, r.ReferencePixelPhysicalValueX,
         r.ReferencePixelPhysicalValueY) = reference
    return r


def write_dicom(path, frames: np.ndarray, *, regions=(), pixel_spacing=None,
                frame_time_ms: float | None = 50.0, frame_time_vector=None,
                photometric: str | None = None, compression: str = "none",
                bits_stored: int | None = None, sop_class: str = US_MULTIFRAME,
                jpeg_quality: int = 95, attributes: dict | None = None) -> Path:
    """``frames`` (T, H, W) gray or (T, H, W, 3) RGB, uint8 (or uint16 for gray) as a DICOM
    file. ``compression``: ``none``, ``jpeg`` (baseline, each frame encoded by OpenCV, colour
    as YBR_FULL_422) or ``rle`` (pydicom's encoder). ``attributes``: set last (None removes
    one)."""
    import cv2
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.encaps import encapsulate
    from pydicom.uid import ExplicitVRLittleEndian as NATIVE
    from pydicom.uid import JPEGBaseline8Bit, RLELossless, generate_uid

    frames = np.asarray(frames)
    colour = frames.ndim == 4
    T, H, W = frames.shape[:3]
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = generate_uid(entropy_srcs=[str(path)])
    meta.TransferSyntaxUID = NATIVE
    ds = Dataset()
    ds.file_meta = meta
    ds.SOPClassUID, ds.SOPInstanceUID = sop_class, meta.MediaStorageSOPInstanceUID
    ds.Modality, ds.Manufacturer = "US", "needlenet tests"
    ds.Rows, ds.Columns, ds.NumberOfFrames = H, W, T
    ds.SamplesPerPixel = 3 if colour else 1
    if colour:
        ds.PlanarConfiguration = 0
    bits = 8 * frames.dtype.itemsize
    ds.BitsAllocated, ds.BitsStored = bits, bits_stored or bits
    ds.HighBit, ds.PixelRepresentation = ds.BitsStored - 1, 0
    ds.PhotometricInterpretation = photometric or ("RGB" if colour else "MONOCHROME2")
    if regions:
        ds.SequenceOfUltrasoundRegions = list(regions)
    if pixel_spacing is not None:
        ds.PixelSpacing = list(pixel_spacing)
    if frame_time_vector is not None:
        ds.FrameTimeVector = list(frame_time_vector)
    elif frame_time_ms is not None:
        ds.FrameTime = frame_time_ms
    if compression == "jpeg":
        enc = []
        for f in frames:
            img = np.ascontiguousarray(f[..., ::-1]) if colour else f  # OpenCV writes BGR
            ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            assert ok
            enc.append(buf.tobytes())
        ds.PixelData = encapsulate(enc)
        ds["PixelData"].VR = "OB"
        ds["PixelData"].is_undefined_length = True
        meta.TransferSyntaxUID = JPEGBaseline8Bit
        if colour:
            ds.PhotometricInterpretation = photometric or "YBR_FULL_422"
    else:
        ds.PixelData = np.ascontiguousarray(frames).tobytes()
        if compression == "rle":
            ds.compress(RLELossless, np.ascontiguousarray(frames))
    for key, value in (attributes or {}).items():  # e.g. InstanceNumber, AcquisitionTime
        if value is None:
            if key in ds:
                delattr(ds, key)
        else:
            setattr(ds, key, value)
    path = Path(path)
    ds.save_as(path, enforce_file_format=True)
    return path
