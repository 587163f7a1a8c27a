"""Frame-grabbed B-mode: a folder of image files or a video file (read with OpenCV), as in
Mathiassen 2017, with the geometry given on the command line or in a sidecar JSON.

The sidecar is ``frames.json`` inside the folder, or ``<video>.json`` (``clip.json`` or
``clip.mp4.json``) next to a video; its keys, all optional:

- ``spacing_mm``: one number (square pixels) or ``[dz, dx]`` (array order: depth, lateral);
- ``origin_mm``: ``[z0, x0]``, the position of the top-left pixel of the (cropped) image;
- ``fps``: frames per second; ``timestamps_s``: one time per frame instead;
- ``modality``: ``inplane`` or ``axial``;
- ``crop``: ``[x, y, w, h]`` in pixels, the image area of a screen capture;
- ``dynamic_range_db``: of the scanner's log compression, when known.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from ._colour_marks import fill_colour_marks
from ._errors import RecordingError
from ._lazy import FrameStack, is_frame_stack
from ._limits import check_allocation, check_frame_shape

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "read_sidecar", "sidecar_path",
           "read_image_folder", "read_video", "apply_crop"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".wmv")
SIDECAR_KEYS = ("spacing_mm", "origin_mm", "fps", "timestamps_s", "modality", "crop",
                "dynamic_range_db")
_MAX_SIDECAR = 64 << 20  # a sidecar holds a few numbers per frame


def sidecar_path(path: Path) -> Path | None:
    """The sidecar JSON of a folder or a video, if there is one."""
    cands = [path / "frames.json"] if path.is_dir() else \
        [path.with_suffix(".json"), path.with_name(path.name + ".json")]
    return next((c for c in cands if c.is_file()), None)


def read_sidecar(path: Path) -> dict:
    """Read and check a sidecar JSON; unknown keys are an error (a misspelt key would
    otherwise be silently ignored)."""
    src = str(path)
    try:
        if path.stat().st_size > _MAX_SIDECAR:
            raise RecordingError(f"{src}: {path.stat().st_size} bytes is no sidecar JSON (at "
                                 f"most {_MAX_SIDECAR} bytes)")
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise RecordingError(f"{src}: not a readable JSON sidecar "
                             f"({type(exc).__name__}: {str(exc)[:200]})") from None
    if not isinstance(d, dict):
        raise RecordingError(f"{src}: the sidecar must be a JSON object")
    unknown = sorted(set(d) - set(SIDECAR_KEYS))
    if unknown:
        raise RecordingError(f"{src}: unknown key {unknown[0]!r}; expected "
                             f"{', '.join(SIDECAR_KEYS)}")

    def numbers(key, sizes):
        v = d[key]
        try:
            a = np.atleast_1d(np.asarray(v, float))
        except (TypeError, ValueError):
            raise RecordingError(f"{src}: key {key!r} must be numbers, got {v!r}") from None
        if a.ndim != 1 or a.size not in sizes or not np.all(np.isfinite(a)):
            raise RecordingError(f"{src}: key {key!r} must be {' or '.join(map(str, sizes))} "
                                 f"finite numbers, got {v!r}")
        return a

    out = {}
    if "spacing_mm" in d:
        out["spacing_mm"] = numbers("spacing_mm", (1, 2))
    if "origin_mm" in d:
        out["origin_mm"] = numbers("origin_mm", (2,))
    if "fps" in d:
        out["fps"] = float(numbers("fps", (1,))[0])
    if "dynamic_range_db" in d:
        out["dynamic_range_db"] = float(numbers("dynamic_range_db", (1,))[0])
    if "timestamps_s" in d:
        v = d["timestamps_s"]
        try:
            out["timestamps_s"] = np.asarray(v, float).ravel()
        except (TypeError, ValueError):
            raise RecordingError(f"{src}: key 'timestamps_s' must be numbers") from None
    if "crop" in d:
        out["crop"] = tuple(int(c) for c in numbers("crop", (4,)))
    if "modality" in d:
        if d["modality"] not in ("inplane", "axial"):
            raise RecordingError(f"{src}: key 'modality' must be 'inplane' or 'axial' for 2D "
                                 f"frames, got {d['modality']!r}")
        out["modality"] = d["modality"]
    return out


def apply_crop(images: np.ndarray, crop, src: str) -> np.ndarray:
    """Cut ``crop = (x, y, w, h)`` (pixels; x along the columns) out of every 2D frame (of a
    :class:`~._lazy.FrameStack`: as each frame is read)."""
    x, y, w, h = (int(c) for c in crop)
    H, W = images.shape[1:3]
    if w < 2 or h < 2 or x < 0 or y < 0 or x + w > W or y + h > H:
        raise RecordingError(f"{src}: crop x,y,w,h = {x},{y},{w},{h} does not fit in frames of "
                             f"{W}x{H} pixels (width x height)")
    cut = images[:, y:y + h, x:x + w]
    return cut if is_frame_stack(cut) else np.ascontiguousarray(cut)


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def _gray(img: np.ndarray) -> np.ndarray:
    import cv2

    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = fill_colour_marks(cv2.cvtColor(img, code), img)
    return img


def has_image_files(path: Path) -> bool:
    """Whether a folder holds a file with an image suffix (a folder of frames)."""
    return any(p.suffix.lower() in IMAGE_SUFFIXES for p in Path(path).iterdir())


def read_image_folder(path: str | os.PathLike) -> FrameStack:
    """Every image file of a folder, in natural order (``f2.png`` before ``f10.png``), as
    uint8 gray frames ``(T, H, W)``; colour is converted to gray (OpenCV's BGR luma), with
    coloured marks drawn over the image filled in (:mod:`._colour_marks`).

    The files are checked here (regular files, headers of a sane size, all alike, the first
    one decoded) and each is decoded when its frame is read: a damaged file found then is a
    :class:`RecordingError` naming the file and the frame."""
    path = Path(path)
    files = sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                   key=_natural_key)
    if not files:
        raise RecordingError(f"{path}: no image files ({', '.join(IMAGE_SUFFIXES)}) or DICOM "
                             "files in the folder")
    sizes = []
    for f in files:
        if not f.is_file():  # a folder, or a FIFO that would never end
            raise RecordingError(f"{f}: not a regular file")
        sizes.append(_check_image_size(f))
    first = _read_image(files[0], 0, None, files[0])
    h, w = first.shape
    for f, size in zip(files, sizes, strict=True):
        if size is not None and size != (h, w):
            raise RecordingError(f"{f}: {size[1]}x{size[0]} pixels, but {files[0].name} has "
                                 f"{w}x{h}")

    def read(i: int) -> np.ndarray:
        return first.copy() if i == 0 else _read_image(files[i], i, first.shape, files[0])

    return FrameStack(read, len(files), first.shape, source=files)


def _read_image(f: Path, i: int, shape, first: Path) -> np.ndarray:
    """Frame ``i`` of a folder, decoded from ``f``: uint8 gray of ``shape`` (that of the
    ``first`` file; None: any)."""
    import cv2

    frame = "" if i == 0 else f" (frame {i})"
    try:
        img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise RecordingError(f"{f}: not a readable image{frame} ({_cv_message(exc)})") from None
    if img is None:
        raise RecordingError(f"{f}: not a readable image{frame}")
    img = _gray(img)
    if img.dtype != np.uint8:
        raise RecordingError(f"{f}: {img.dtype} pixels{frame}; needlenet reads 8-bit frames")
    if shape is not None and img.shape != tuple(shape):
        raise RecordingError(f"{f}: {img.shape[1]}x{img.shape[0]} pixels{frame}, but "
                             f"{first.name} has {shape[1]}x{shape[0]}")
    return img


def _cv_message(exc) -> str:
    """The one line of an OpenCV error that says what failed."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return (lines[-1] if lines else type(exc).__name__)[:200]


def _check_image_size(f: Path) -> tuple[int, int] | None:
    """The size ``(h, w)`` an image file's header claims (read by Pillow, which reads the
    header only; None when Pillow cannot parse it), checked before OpenCV allocates it: a
    damaged header claiming 50000 x 50000 pixels is an error naming the file, not gigabytes
    allocated for a few bytes of data."""
    from PIL import Image

    Image.MAX_IMAGE_PIXELS = None  # the check below replaces Pillow's bomb warning
    try:
        with Image.open(f) as im:
            w, h = im.size
            bands = len(im.getbands())
            depth = 2 if im.mode in ("I;16", "I;16B", "I;16L", "I") else 1
    except Exception:  # Pillow cannot parse it: OpenCV will say so
        return None
    check_frame_shape((h, w), str(f), "its header's image size")
    check_allocation((h, w, bands), depth, str(f), "its header's image size")
    return h, w


def read_video(path: str | os.PathLike) -> tuple[FrameStack, float | None, list[str]]:
    """Every frame of a video (OpenCV ``VideoCapture``) as uint8 gray ``(T, H, W)``, the
    container's frame rate (None when it does not say), and notes for the user (fewer frames
    decoded than the container announces: a truncated or damaged file).

    The video is decoded here once to count and check its frames, keeping none of them, and
    again frame by frame as the frames are read (forwards; reading an earlier frame starts the
    decoder again from the first)."""
    import cv2

    src = str(path)
    if not Path(path).is_file():  # OpenCV would wait on a FIFO for ever
        raise RecordingError(f"{src}: not a regular file")
    cap = _open_video(src)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        announced = float(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0.0)
        n, shape = 0, None
        while True:
            try:
                ok, img = cap.read()
            except cv2.error as exc:
                raise RecordingError(f"{src}: frame {n} cannot be decoded "
                                     f"({_cv_message(exc)})") from None
            if not ok:
                break
            img = _gray(img)
            if shape is not None and img.shape != shape:
                raise RecordingError(f"{src}: frame {n} changes size")
            check_frame_shape(img.shape, src, "frame size")
            shape, n = img.shape, n + 1
    finally:
        cap.release()
    if not n:
        raise RecordingError(f"{src}: no frames could be decoded")
    notes = []
    if np.isfinite(announced) and announced > n:
        notes.append(f"{src}: decoded {n} of the {int(announced)} frames the "
                     "container announces; the file may be truncated or damaged")
    stack = FrameStack(_VideoDecoder(src, shape).read, n, shape, source=src)
    return stack, (fps if np.isfinite(fps) and fps > 0 else None), notes


def _open_video(src: str):
    import cv2

    try:
        cap = cv2.VideoCapture(src)
    except cv2.error as exc:
        raise RecordingError(f"{src}: OpenCV cannot open this video ({_cv_message(exc)})"
                             ) from None
    if not cap.isOpened():
        cap.release()
        raise RecordingError(f"{src}: OpenCV cannot open this video (damaged file, or a "
                             "codec it lacks)")
    return cap


class _VideoDecoder:
    """Frames of a video decoded on demand, in order: frame ``i`` after frame ``i - 1`` costs
    one decode; a frame further on skips the ones between, an earlier one reopens the video."""

    def __init__(self, src: str, shape: tuple[int, ...]):
        self.src, self.shape = src, shape
        self.cap, self.pos = None, 0

    def read(self, i: int) -> np.ndarray:
        import cv2

        try:
            if self.cap is None or i < self.pos:
                if self.cap is not None:
                    self.cap.release()
                self.cap, self.pos = _open_video(self.src), 0
            while self.pos < i:
                if not self.cap.grab():
                    break
                self.pos += 1
            ok, img = self.cap.read() if self.pos == i else (False, None)
        except cv2.error as exc:
            raise RecordingError(f"{self.src}: frame {i} cannot be decoded "
                                 f"({_cv_message(exc)})") from None
        if not ok:
            raise RecordingError(f"{self.src}: frame {i} cannot be decoded (the file changed "
                                 "since it was opened?)")
        self.pos += 1
        img = _gray(img)
        if img.shape != self.shape:
            raise RecordingError(f"{self.src}: frame {i} changes size")
        return img
