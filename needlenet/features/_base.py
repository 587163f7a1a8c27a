"""The seam between images and back ends: a FeatureSource turns a frame into likelihood maps.

Every tracker takes a :class:`FeatureSource`. Classical sources compute the hand-tuned feature
of a paper (intensity, Carriere's variance image, Frangi's tubularness); a learned source (an
ONNX model) predicts shaft and tip probability maps. Same data, same back end, only the
features differ: that is how learned and classical features are compared honestly.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from synth import Grid

__all__ = ["Frame", "Likelihood", "FeatureSource", "IntensityFeatures", "FrameError",
           "check_frame"]


class FrameError(ValueError):
    """A frame that cannot be measured (empty, constant, NaN, wrong shape)."""


@dataclass
class Frame:
    """One image of a sequence with what a tracker may know about it.

    ``image`` is uint8 (or float) in array order ([z, x] or [z, y, x]); ``grid`` maps it to
    millimetres in the probe frame. ``insertion_speed_mm_s`` is a robot's velocity measurement
    along the needle when one is available (Mathiassen 2017's KF_v / PF_v); ``probe_pose`` the
    probe-to-world transform when known.
    """

    image: np.ndarray
    grid: Grid
    t: float = 0.0
    index: int = 0
    insertion_speed_mm_s: float | None = None
    probe_pose: np.ndarray | None = None
    extras: dict = field(default_factory=dict)

    @classmethod
    def from_image(cls, image, spacing_mm, *, t: float = 0.0, index: int = 0,
                   origin_mm=None, insertion_speed_mm_s: float | None = None,
                   probe_pose=None) -> Frame:
        """A frame of your own: ``image`` (H, W) for a 2D frame or (D, H, W) for a volume,
        in array order (depth first); ``spacing_mm`` one number (square pixels) or one per
        axis, depth first; ``origin_mm`` the position of pixel 0 (default 0), depth first;
        ``t`` its time (s); ``probe_pose`` the probe-to-world transform (4 x 4) when a
        tracker follows the probe. A ValueError names what does not fit."""
        im = np.asarray(image)
        if im.ndim not in (2, 3):
            raise ValueError(f"Frame.from_image: image must be 2D (H, W) or 3D (D, H, W), got "
                             f"shape {im.shape} (convert colour frames to gray first)")
        if im.dtype.kind not in "uif":
            raise ValueError(f"Frame.from_image: image must hold numbers, got {im.dtype}")
        sp = np.atleast_1d(np.asarray(spacing_mm, float))
        if sp.size == 1:
            sp = np.repeat(sp, im.ndim)
        if sp.shape != (im.ndim,) or not np.all(np.isfinite(sp)) or np.any(sp <= 0):
            raise ValueError(f"Frame.from_image: spacing_mm must be one positive number or "
                             f"{im.ndim} (depth first), got {np.asarray(spacing_mm).tolist()}")
        org = np.zeros(im.ndim) if origin_mm is None else np.asarray(origin_mm, float)
        if org.shape != (im.ndim,) or not np.all(np.isfinite(org)):
            raise ValueError(f"Frame.from_image: origin_mm must be {im.ndim} finite numbers "
                             f"(depth first), got {np.asarray(origin_mm).tolist()}")
        if not np.isfinite(t):
            raise ValueError(f"Frame.from_image: t must be a finite time in seconds, got {t}")
        pose = None if probe_pose is None else np.asarray(probe_pose, float)
        if pose is not None and (pose.shape != (4, 4) or not np.all(np.isfinite(pose))):
            raise ValueError("Frame.from_image: probe_pose must be a 4 x 4 matrix of finite "
                             f"numbers, got shape {pose.shape}")
        grid = Grid(im.shape, tuple(float(v) for v in sp), tuple(float(v) for v in org))
        return cls(im, grid, float(t), int(index), insertion_speed_mm_s, pose)


@dataclass
class Likelihood:
    """Feature maps on the frame's grid, float32 in [0, 1].

    ``shaft``: where the needle's shaft is (for classical sources the paper's feature image).
    ``tip``: where the tip is, or ``None`` when the source has no tip channel (the tracker then
    uses its paper's tip features).
    """

    shaft: np.ndarray
    tip: np.ndarray | None = None
    source: str = ""


def check_frame(frame: Frame) -> None:
    """Raise :class:`FrameError` for a frame no feature can be measured on."""
    im = np.asarray(frame.image)
    if im.ndim != frame.grid.ndim or im.shape != frame.grid.shape:
        raise FrameError(f"frame {frame.index}: image shape {im.shape} does not match the grid "
                         f"{frame.grid.shape}")
    if im.size == 0:
        raise FrameError(f"frame {frame.index}: empty image")
    if im.dtype.kind == "f" and not np.all(np.isfinite(im)):
        raise FrameError(f"frame {frame.index}: image contains NaN or infinity")
    if im.max() == im.min():
        raise FrameError(f"frame {frame.index}: constant image")


class FeatureSource(ABC):
    """Turns a frame (or a region of it) into likelihood maps on the frame's grid."""

    kind: str = "classical"  # or "learned"
    name: str = ""

    @abstractmethod
    def likelihood(self, frame: Frame, roi: tuple[slice, ...] | None = None) -> Likelihood:
        """Maps for the whole frame; with ``roi``, only that region needs to be valid."""

    def native_likelihood(self, frame: Frame) -> tuple[Likelihood, Grid]:
        """Maps for the whole frame on the grid the source computes them on, and that grid. A
        tracker that resamples the maps to a working grid of its own reads them here and
        skips their return to the frame's grid. By default the frame's grid."""
        return self.likelihood(frame), frame.grid


class IntensityFeatures(FeatureSource):
    """The image itself, scaled to [0, 1]: the feature of intensity-threshold methods
    (Chatelain eq. 1 and 15, Zhao eq. B1, Mathiassen's rays)."""

    name = "intensity"

    def likelihood(self, frame: Frame, roi=None) -> Likelihood:
        im = np.asarray(frame.image)
        scale = 255.0 if im.dtype == np.uint8 else max(float(np.nanmax(im)), 1e-12)
        return Likelihood(shaft=im.astype(np.float32) / np.float32(scale), tip=None,
                          source=self.name)
