"""One entry point for recordings of every kind, and PLUS output of sequences and results.

:func:`load_recording` gives the same :class:`synth.Sequence` as ``synth.load_sequence``, so
every tracker runs on it unchanged; :func:`save_plus_sequence` writes a sequence (with its
labels, or with a tracker's estimates) as a PLUS sequence metafile that 3D Slicer's Sequences
module replays: the image frames and, per frame,

- ``ProbeToReferenceTransform``: the sequence's ``probe_pose`` (probe frame -> world), when it
  has one; without it the reference frame is the probe frame;
- ``NeedleTipToReferenceTransform``: origin at the needle tip, +Z along the insertion direction
  (+Y along the probe's elevation axis for a needle in the image plane); status ``OK`` when the
  tip is known (a label) or tracked, ``INVALID`` (identity matrix, as PLUS writes) while the
  tracker is searching or has lost the needle;
- ``NeedleEntryToReferenceTransform``: the entry point (labels with ``entry_mm``);
- custom frame fields ``NeedleTipVisible`` (labels) and ``NeedleTrackerStatus`` (results).

The probe frame is the sequence file's: x lateral, y elevation, z depth, in mm; a 2D frame
lies in its y = 0 plane, and ``ElementSpacing`` / ``Offset`` place its pixels there
(pixel (i, j) at x = Offset[0] + i * ElementSpacing[0], z = Offset[1] + j * ElementSpacing[1]).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ._dicom import DICOM_SUFFIXES, is_dicom, read_dicom
from ._dicom_series import dicom_files, read_dicom_series
from ._errors import RecordingError
from ._frames import (
    VIDEO_SUFFIXES,
    apply_crop,
    has_image_files,
    read_image_folder,
    read_sidecar,
    read_video,
    sidecar_path,
)
from ._lazy import is_frame_stack
from ._limits import (
    MAX_POSITION_MM,
    check_extent,
    check_fps,
    check_frame_times,
    check_meta_numbers,
    check_origin,
    check_spacing,
    check_transforms,
)
from ._metaimage import PLUS_SUFFIXES, PlusSequence, read_plus, write_plus
from ._still_marks import fill_still_marks

__all__ = ["load_recording", "save_plus_sequence", "sequence_to_plus", "needle_tip_matrix",
           "parse_spacing", "parse_crop", "RECORDING_KINDS", "DEFAULT_DYNAMIC_RANGE_DB",
           "NEEDLE_TIP", "NEEDLE_ENTRY", "PROBE_POSE"]

RECORDING_KINDS = ".npz, .mha/.mhd (PLUS), .nrrd/.nhdr, DICOM (.dcm, or no suffix; a folder " \
    "of single-frame files), a folder of images, or a video (" + ", ".join(VIDEO_SUFFIXES) + ")"
# the suffixes of the other kinds: a file with none of them is read as DICOM when it carries
# DICOM's signature (scanners export IM_0001)
KNOWN_SUFFIXES = (".npz", ".nrrd", ".nhdr", *PLUS_SUFFIXES, *VIDEO_SUFFIXES)
DEFAULT_DYNAMIC_RANGE_DB = 60.0  # recorded in meta as assumed when the file does not say
NEEDLE_TIP, NEEDLE_ENTRY, PROBE_POSE = "NeedleTipToReference", "NeedleEntryToReference", \
    "ProbeToReference"
_META_FIELD = "NeedlenetSequence"  # header field: modality, dynamic range and meta as JSON


# -- small parsers shared with the CLI -----------------------------------------------------

def parse_spacing(text: str | float | list, what: str = "--spacing") -> np.ndarray:
    """``"0.1"`` (square pixels) or ``"DZ,DX"`` / ``"DZ,DY,DX"`` (array order) -> mm."""
    try:
        v = np.asarray([float(s) for s in str(text).replace(" ", "").split(",")]) \
            if isinstance(text, str) else np.atleast_1d(np.asarray(text, float))
    except ValueError:
        raise RecordingError(f"{what} {text!r}: expected MM or DZ,DX in millimetres") from None
    if v.ndim != 1 or v.size not in (1, 2, 3) or not np.all(np.isfinite(v)) or np.any(v <= 0):
        raise RecordingError(f"{what} {text!r}: expected positive MM or DZ,DX (mm per pixel)")
    return v


def parse_crop(text: str) -> tuple[int, int, int, int]:
    """``"X,Y,W,H"`` in pixels -> a tuple."""
    try:
        v = tuple(int(s) for s in text.replace(" ", "").split(","))
    except ValueError:
        v = ()
    if len(v) != 4:
        raise RecordingError(f"--crop {text!r}: expected X,Y,W,H in pixels")
    return v


# -- needle transforms --------------------------------------------------------------------------

def _lift(p, nd: int) -> np.ndarray:
    """A point or vector in point order, (x, z) or (x, y, z), as (x, y, z) (y = 0 in 2D)."""
    p = np.asarray(p, float)
    return p if nd == 3 else np.array([p[0], 0.0, p[1]])


def needle_tip_matrix(tip, direction=None) -> np.ndarray:
    """NeedleTipToProbe: origin at ``tip``, +Z along ``direction`` (point order, 2D or 3D);
    +X = e_y x Z and +Y = Z x X, so that +Y is the probe's elevation axis for a needle in the
    image plane (e_x is used instead of e_y when the needle runs along the elevation axis).
    Without a direction the rotation is the identity."""
    tip = np.asarray(tip, float)
    nd = tip.size
    T = np.eye(4)
    T[:3, 3] = _lift(tip, nd)
    if direction is None:
        return T
    z = _lift(direction, nd)
    n = np.linalg.norm(z)
    if not np.isfinite(n) or n < 1e-12:
        return T
    z = z / n
    a = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    return T


# -- writing ----------------------------------------------------------------------------------

def sequence_to_plus(seq, estimates=None) -> tuple[PlusSequence, dict[str, str]]:
    """A sequence (with its labels, or with ``estimates``, a tracker's per-frame
    :class:`~needlenet.trackers.NeedleEstimate`) as PLUS content and extra header fields."""
    T = seq.n_frames
    pose = None if seq.probe_pose is None else np.asarray(seq.probe_pose, float)
    transforms, ok, fields = {}, {}, {}
    if pose is not None:
        transforms[PROBE_POSE], ok[PROBE_POSE] = pose, np.ones(T, bool)

    def to_ref(i, m):
        return m if pose is None else pose[i] @ m

    tips = np.repeat(np.eye(4)[None], T, axis=0)
    good = np.zeros(T, bool)
    if estimates is not None:
        if len(estimates) != T:
            raise RecordingError(f"{len(estimates)} estimates for {T} frames")
        for i, e in enumerate(estimates):
            tip = None if e.tip_mm is None else np.asarray(e.tip_mm, float)
            if e.status.value == "tracking" and tip is not None and np.all(np.isfinite(tip)):
                tips[i], good[i] = to_ref(i, needle_tip_matrix(tip, e.direction)), True
        transforms[NEEDLE_TIP], ok[NEEDLE_TIP] = tips, good
        fields["NeedleTrackerStatus"] = [e.status.value for e in estimates]
    elif seq.tip_mm is not None:
        d = seq.direction
        for i in range(T):
            tip = np.asarray(seq.tip_mm[i], float)
            if np.all(np.isfinite(tip)):
                di = None if d is None or not np.all(np.isfinite(d[i])) else d[i]
                tips[i], good[i] = to_ref(i, needle_tip_matrix(tip, di)), True
        transforms[NEEDLE_TIP], ok[NEEDLE_TIP] = tips, good
        if seq.entry_mm is not None:
            transforms[NEEDLE_ENTRY] = np.stack(
                [to_ref(i, needle_tip_matrix(seq.entry_mm[i], None)) for i in range(T)])
            ok[NEEDLE_ENTRY] = np.ones(T, bool)
        if seq.visible is not None:
            fields["NeedleTipVisible"] = ["True" if v else "False" for v in seq.visible]
    plus = PlusSequence(images=seq.images, spacing_mm=np.asarray(seq.spacing_mm, float),
                        origin_mm=np.asarray(seq.origin_mm, float),
                        timestamps_s=np.asarray(seq.timestamps_s, float), transforms=transforms,
                        transform_ok=ok, frame_fields=fields)
    extra = {_META_FIELD: json.dumps({"modality": seq.modality,
                                      "dynamic_range_db": float(seq.dynamic_range_db),
                                      "meta": seq.meta}, sort_keys=True, default=str)}
    return plus, extra


def save_plus_sequence(seq, path: str | os.PathLike, estimates=None, *, compress: bool = True,
                       overwrite: bool = False) -> list[Path]:
    """Write ``seq`` (and its labels, or ``estimates``) as a PLUS sequence metafile
    (``.mha``/``.seq.mha``, or ``.mhd`` with a ``.raw``/``.zraw``); returns the files written.
    Written whole or not at all; an existing output is refused unless ``overwrite``."""
    plus, extra = sequence_to_plus(seq, estimates)
    return write_plus(path, plus, compress=compress, overwrite=overwrite, extra_fields=extra)


# -- reading ----------------------------------------------------------------------------------

def _timestamps(T, file_ts, fps, src, where="frame times"):
    if fps is not None:
        return np.arange(T) / check_fps(fps, src, "fps (--fps)")
    if file_ts is not None:
        ts = np.asarray(file_ts, float)
        if ts.shape != (T,):
            raise RecordingError(f"{src}: {ts.size} timestamps for {T} frames")
        if not np.all(np.isfinite(ts)):
            raise RecordingError(f"{src}: {where}: frame "
                                 f"{int(np.flatnonzero(~np.isfinite(ts))[0])} has no finite "
                                 "time; pass fps (--fps) to use a fixed frame rate instead")
        if T > 1 and np.any(np.diff(ts) < 0):
            raise RecordingError(f"{src}: frame timestamps decrease (frame "
                                 f"{int(np.flatnonzero(np.diff(ts) < 0)[0]) + 1}); pass fps "
                                 "(--fps) to use a fixed frame rate instead")
        check_frame_times(ts, src, where)
        return ts
    if T == 1:
        return np.zeros(1)
    raise RecordingError(f"{src}: no frame times in the recording ({where}); pass fps "
                         "(--fps N)")


def _labels_from_plus(plus: PlusSequence, pose, modality, grid, src) -> dict:
    """Labels from NeedleTipToReference (and NeedleEntryToReference, NeedleTipVisible)."""
    if NEEDLE_TIP not in plus.transforms:
        return {}
    nd = grid.ndim
    inv = None if pose is None else np.linalg.inv(pose)
    mats = plus.transforms[NEEDLE_TIP]
    if inv is not None:
        mats = inv @ mats
    good = plus.transform_ok[NEEDLE_TIP]
    pick = [0, 2] if nd == 2 else [0, 1, 2]
    tip = np.where(good[:, None], mats[:, pick, 3], np.nan)
    d = mats[:, pick, 2]
    n = np.linalg.norm(d, axis=1, keepdims=True)
    ok_dir = good[:, None] & np.isfinite(n) & (n > 1e-12)
    direction = np.where(ok_dir, d / np.where(ok_dir, n, 1.0), np.nan)
    out = {"tip_mm": tip, "direction": direction}
    vis = plus.frame_fields.get("NeedleTipVisible")
    if vis is not None and all(v is not None for v in vis):
        out["visible"] = np.array([v.strip().lower() == "true" for v in vis])
    elif modality == "axial":
        out["visible"] = good.copy()
    else:
        out["visible"] = good & grid.contains(np.nan_to_num(tip, nan=-1e9))
    if NEEDLE_ENTRY in plus.transforms and np.all(plus.transform_ok[NEEDLE_ENTRY]):
        e = plus.transforms[NEEDLE_ENTRY]
        if inv is not None:
            e = inv @ e
        out["entry_mm"] = e[:, pick, 3]
    elif modality == "volume":
        return {}  # Zhao's metrics need the entry point; without it the labels are unusable
    return out


def _check_label_positions(v, src: str, key: str) -> None:
    """Label positions (NaN where unknown) within :data:`~._limits.MAX_POSITION_MM` of the
    probe: a tip at 1e300 mm overflows every error computed from it."""
    if v is None:
        return
    a = np.asarray(v, float)
    far = np.isfinite(a) & (np.abs(a) > MAX_POSITION_MM)
    if np.any(far):
        frame = int(np.argwhere(far)[0][0])
        raise RecordingError(f"{src}: {key} of frame {frame} lies more than "
                             f"{MAX_POSITION_MM:g} mm from the probe")


def _drop_invalid_frames(seq_kw: dict, image_ok: np.ndarray, src: str) -> str:
    """Remove the frames PLUS marks ``ImageStatus = INVALID`` (a frame grabber's dropped or
    torn frames) from every per-frame entry of ``seq_kw``; returns the note for the user."""
    bad = np.flatnonzero(~image_ok)
    if bad.size == len(image_ok):
        raise RecordingError(f"{src}: every frame is marked ImageStatus = INVALID; nothing to "
                             "track")
    T = len(image_ok)
    for key, value in list(seq_kw.items()):
        if (isinstance(value, np.ndarray) or is_frame_stack(value)) and value.ndim >= 1 \
                and value.shape[0] == T and key not in ("spacing_mm", "origin_mm"):
            seq_kw[key] = value[image_ok]
    shown = ", ".join(str(int(i)) for i in bad[:10]) + (" ..." if bad.size > 10 else "")
    return (f"{src}: skipped {bad.size} of {T} frames marked ImageStatus = INVALID "
            f"(frames {shown}); frame numbers below count the frames kept")


def load_recording(path: str | os.PathLike, *, modality: str | None = None,
                   spacing_mm=None, crop=None, fps: float | None = None,
                   pose_transform: str = PROBE_POSE):
    """Read a recording of any supported kind as a :class:`synth.Sequence`.

    By suffix: ``.npz`` (the sequence file), ``.mha``/``.mhd`` (a PLUS sequence metafile,
    see :mod:`needlenet.io._metaimage`), ``.nrrd``/``.nhdr`` (see :mod:`needlenet.io._nrrd`),
    DICOM (``.dcm``, or any file with DICOM's signature: a scanner's cine loop, its spacing,
    image region and frame times read from the file, see :mod:`needlenet.io._dicom`), a folder
    of image files or a video (see :mod:`needlenet.io._frames`; a sidecar JSON may give the
    geometry).

    - ``modality``: for 2D frames ``inplane`` (the default) or ``axial``; 3D frames are
      ``volume``. A file written by needlenet carries its own.
    - ``spacing_mm``: mm per pixel, one number or one per array axis ([depth, lateral] or
      [depth, elevation, lateral]); overrides the file's (PLUS files often say 1 1 1, pixels).
      Required when the file gives none.
    - ``crop``: ``(x, y, w, h)`` in pixels of 2D frames (the image area of a screen capture;
      a DICOM file's calibrated image region when not given).
    - ``fps``: a fixed frame rate, overriding the file's frame times.
    - ``pose_transform``: the PLUS transform used as ``probe_pose`` (when every frame's
      status is OK).

    A PLUS file's ``NeedleTipToReference`` transforms become labels (``tip_mm``,
    ``direction``, ``visible``, and ``entry_mm`` from ``NeedleEntryToReference``).
    Raises :class:`RecordingError` naming the file and the field or option at fault.
    """
    import synth

    path = Path(path)
    src = str(path)
    if modality is not None and modality not in synth.MODALITIES:
        raise RecordingError(f"{src}: modality must be one of {synth.MODALITIES}, got "
                             f"{modality!r}")
    if not path.exists():
        raise FileNotFoundError(f"{src}: no such recording")
    if not (path.is_file() or path.is_dir()):  # reading a FIFO or a device never ends
        raise RecordingError(f"{src}: not a regular file or a folder (a FIFO, a socket or a "
                             "device?); give a recording file")
    suffix = path.suffix.lower()
    kw: dict = {}
    meta: dict = {"source": src}
    file_ts = None
    file_modality = None
    sidecar: dict = {}
    plus = None
    warnings: list[str] = []
    dicom = None  # a DICOM recording: one file, or a folder of single frames
    if path.is_dir() and not has_image_files(path):
        series = dicom_files(path)
        dicom = read_dicom_series(path, series) if series else None
    elif path.is_file() and (suffix in DICOM_SUFFIXES or (
            suffix not in KNOWN_SUFFIXES and is_dicom(path))):
        dicom = read_dicom(path)
    if dicom is not None:
        images, file_sp, origin, file_ts = dicom.images, dicom.spacing_mm, dicom.origin_mm, \
            dicom.timestamps_s
        if crop is None:
            crop = dicom.crop  # the scanner's image region: its text and scales cut away
        elif dicom.crop is not None:
            dicom.meta["dicom"]["region_crop_replaced"] = list(dicom.crop)
        warnings += dicom.notes
        meta.update(dicom.meta)
    elif path.is_dir() or suffix in VIDEO_SUFFIXES:
        sc = sidecar_path(path)
        if sc is not None:
            sidecar = read_sidecar(sc)
            meta["sidecar"] = str(sc)
        if path.is_dir():
            images, container_fps = read_image_folder(path), None
            meta["format"] = "image folder"
        else:
            images, container_fps, notes = read_video(path)
            warnings += notes
            meta["format"] = "video"
        file_sp, origin = sidecar.get("spacing_mm"), sidecar.get("origin_mm")
        file_ts = sidecar.get("timestamps_s")
        if fps is None and file_ts is None:
            fps = sidecar.get("fps", container_fps)
        file_modality = sidecar.get("modality")
        if crop is None:
            crop = sidecar.get("crop")
        if "dynamic_range_db" in sidecar:
            kw["dynamic_range_db"] = sidecar["dynamic_range_db"]
    elif suffix == ".npz":
        try:
            seq = synth.load_sequence(path)
        except synth.SequenceFileError as exc:
            raise RecordingError(str(exc)) from None
        images, file_sp, origin = seq.images, seq.spacing_mm, seq.origin_mm
        file_ts, file_modality = seq.timestamps_s, seq.modality
        kw = {k: v for k, v in seq.as_dict().items()
              if k not in ("images", "spacing_mm", "origin_mm", "timestamps_s", "modality",
                           "meta")}
        meta = dict(seq.meta)
    elif suffix in PLUS_SUFFIXES:
        plus = read_plus(path)
        images, file_sp, origin, file_ts = plus.images, plus.spacing_mm, plus.origin_mm, \
            plus.timestamps_s
        meta["format"] = "plus"
        meta["plus"] = {"orientation": plus.orientation,
                        "transforms": sorted(plus.transforms),
                        "invalid_images": np.flatnonzero(~plus.image_ok).tolist()}
        if plus.intensity_range is not None:
            meta["intensity_range"] = list(plus.intensity_range)
        warnings += plus.notes
        if _META_FIELD in plus.fields:
            try:
                saved = json.loads(plus.fields[_META_FIELD])
                file_modality = saved["modality"]
                kw["dynamic_range_db"] = float(saved["dynamic_range_db"])
                meta = {**saved["meta"], **meta}
            except (json.JSONDecodeError, KeyError, TypeError, ValueError, RecursionError):
                raise RecordingError(f"{src}: header field {_META_FIELD} is not needlenet's "
                                     "JSON") from None
            if file_modality not in synth.MODALITIES:
                raise RecordingError(f"{src}: header field {_META_FIELD}: modality "
                                     f"{file_modality!r:.40} is not one of {synth.MODALITIES}")
    elif suffix in (".nrrd", ".nhdr"):
        from ._nrrd import read_nrrd

        rec = read_nrrd(path)
        images, file_sp, origin, file_ts = rec.images, rec.spacing_mm, rec.origin_mm, \
            rec.timestamps_s
        warnings += rec.meta.pop("warnings", [])
        meta.update(format="nrrd", **rec.meta)
    else:
        raise RecordingError(f"{src}: unknown recording type {suffix or '(no suffix)'!r}; "
                             f"expected {RECORDING_KINDS}")

    T, nd = images.shape[0], images.ndim - 1
    if nd == 3:
        if modality not in (None, "volume"):
            raise RecordingError(f"{src}: holds 3D volumes; modality {modality!r} needs 2D "
                                 "frames")
        modality = "volume"
    else:
        if modality == "volume":
            raise RecordingError(f"{src}: holds 2D frames; modality 'volume' needs 3D volumes")
        modality = modality or file_modality or "inplane"
        if modality == "volume":
            modality = "inplane"
    sp = spacing_mm if spacing_mm is not None else file_sp
    if sp is None:
        where = {"plus": "ElementSpacing", "nrrd": "space directions / spacings",
                 "dicom": "a calibrated SequenceOfUltrasoundRegions item or PixelSpacing"}.get(
            meta.get("format"), "a sidecar JSON's spacing_mm")
        raise RecordingError(f"{src}: no pixel spacing ({where}); pass spacing_mm "
                             f"(--spacing MM or --spacing {'DZ,DY,DX' if nd == 3 else 'DZ,DX'})")
    sp = parse_spacing(sp if isinstance(sp, str) else np.asarray(sp, float), "spacing_mm")
    if sp.size == 1:
        sp = np.repeat(sp, nd)
    if sp.size != nd:
        raise RecordingError(f"{src}: spacing {sp.tolist()} has {sp.size} values for {nd}D "
                             "frames")
    check_spacing(sp, src, "--spacing" if spacing_mm is not None else {
        "plus": "ElementSpacing", "nrrd": "space directions / spacings",
        "dicom": "the ultrasound region's PhysicalDeltaY/X or PixelSpacing", "image folder":
        "the sidecar's spacing_mm", "video": "the sidecar's spacing_mm"}.get(
        meta.get("format"), "spacing_mm"))
    if spacing_mm is not None:
        meta["spacing_from"] = "argument"
    origin = np.zeros(nd) if origin is None else np.asarray(origin, float)
    if origin.shape != (nd,):
        raise RecordingError(f"{src}: origin {origin.tolist()} has {origin.size} values for "
                             f"{nd}D frames")
    check_origin(origin, src, {"plus": "Offset", "nrrd": "space origin / axis mins",
                               "dicom": "the ultrasound region's reference pixel",
                               "image folder": "the sidecar's origin_mm",
                               "video": "the sidecar's origin_mm"}.get(meta.get("format"),
                                                                       "origin_mm"))
    if crop is not None:
        if nd != 2:
            raise RecordingError(f"{src}: crop applies to 2D frames only")
        images = apply_crop(images, crop, src)
        x, y = int(crop[0]), int(crop[1])
        origin = origin + np.array([y, x]) * sp
        meta["crop"] = [int(c) for c in crop]
    check_extent(images.shape[1:], sp, src, "spacing")
    if nd == 2:
        images = fill_still_marks(images, meta)
    check_meta_numbers(meta, src)
    kw.setdefault("dynamic_range_db", DEFAULT_DYNAMIC_RANGE_DB)
    if "dynamic_range_db" not in sidecar and meta.get("format") in ("image folder", "video",
                                                                    "nrrd", "dicom"):
        meta["dynamic_range_db_assumed"] = True
    ts = _timestamps(T, file_ts, fps, src, {
        "plus": "Seq_FrameNNNN_Timestamp on every frame",
        "nrrd": "the list axis' 'index values'",
        "dicom": "FrameTimeVector, FrameTime, CineRate or RecommendedDisplayFrameRate"}.get(
            meta.get("format"), "fps or timestamps_s"))
    seq_kw = dict(images=images, spacing_mm=sp, origin_mm=origin, modality=modality,
                  timestamps_s=ts, meta=meta, **kw)
    if plus is not None:
        for name in {pose_transform, NEEDLE_TIP, NEEDLE_ENTRY} & set(plus.transforms):
            check_transforms(plus.transforms[name], plus.transform_ok[name], src,
                             f"Seq_FrameNNNN_{name}Transform")
        pose = plus.transforms.get(pose_transform)
        if pose is not None and np.all(plus.transform_ok[pose_transform]):
            seq_kw["probe_pose"] = pose
        elif pose is not None:
            meta["plus"]["pose_invalid_frames"] = np.flatnonzero(
                ~plus.transform_ok[pose_transform]).tolist()
        grid = synth.Grid(images.shape[1:], tuple(sp), tuple(origin))
        seq_kw.update(_labels_from_plus(plus, seq_kw.get("probe_pose"), modality, grid, src))
        if not plus.image_ok.all():
            warnings.append(_drop_invalid_frames(seq_kw, plus.image_ok, src))
    if warnings:
        meta["warnings"] = warnings
    if modality != file_modality and file_modality is not None and suffix == ".npz":
        raise RecordingError(f"{src}: holds {file_modality!r} frames, not {modality!r}")
    if seq_kw.get("probe_pose") is not None:
        check_transforms(seq_kw["probe_pose"], np.ones(len(seq_kw["probe_pose"]), bool), src,
                         "probe_pose (frame NNNN)")
    for key in ("tip_mm", "entry_mm", "tip_3d_mm", "centerline_mm"):
        _check_label_positions(seq_kw.get(key), src, key)
    try:
        return synth.validate_sequence(synth.Sequence(**seq_kw), source=src)
    except synth.SequenceFileError as exc:
        raise RecordingError(str(exc)) from None
