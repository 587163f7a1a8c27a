"""One interface for every tracker: detect, predict an ROI/VOI, measure, filter, notice a
lost needle and find it again; report status, tip, direction, covariance and latency."""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import Enum

import numpy as np

from ..features import FeatureSource, Frame, FrameError, check_frame
from ._details import EstimateDetails
from ._margins import zero_margins

__all__ = ["Status", "NeedleEstimate", "Tracker", "RngLike", "frames_from_sequence",
           "GAUGE_RADII_MM", "radius_variance"]

# the radii of the needles a tracker may meet when not told the gauge (25-14 G outer radii, mm)
GAUGE_RADII_MM = (0.257, 1.054)


def radius_variance(radii_mm: tuple[float, float], owner: str) -> float:
    """The variance (mm^2) of a needle radius spread evenly over ``radii_mm`` = (a, b):
    (b - a)^2 / 12. ``owner`` names the parameter in the error for a bad range."""
    a, b = (float(v) for v in radii_mm)
    if not 0.0 <= a <= b <= 10.0:
        raise ValueError(f"{owner} must be (low, high) radii with 0 <= low <= high <= 10 mm, "
                         f"got {tuple(radii_mm)}")
    return (b - a) ** 2 / 12.0


def tip_spread_covariance(direction: np.ndarray, spread_mm: float) -> np.ndarray:
    """Where the tip lies along the needle when a frame offered places for it ``spread_mm``
    apart (the in-plane `line` tracker's tip step, the volume trackers' measurement): one of
    them is right and the frame does not say which, so the tip is taken as anywhere between
    them, evenly: variance spread^2 / 12 along ``direction`` (2D or 3D). Places that agree
    add nothing; a map running on past the echo's end (the streak of unfocused imaging past
    a tip, a tissue line continuing the needle) adds what that disagreement leaves unknown."""
    d = np.asarray(direction, float)
    return np.outer(d, d) * (float(spread_mm) ** 2 / 12.0)


class Status(str, Enum):
    SEARCHING = "searching"  # no needle found yet (or re-detecting after a reset)
    TRACKING = "tracking"
    LOST = "lost"  # was tracking; the needle left the image or vanished


@dataclass
class NeedleEstimate:
    """A tracker's output for one frame. Points are in millimetres, point order, probe frame
    ((x, z) for 2D, (x, y, z) for 3D), like the sequence file's labels. ``details`` holds what
    the tracker reports beyond these fields (see :mod:`._details`)."""

    t: float
    status: Status
    tip_mm: np.ndarray | None = None
    direction: np.ndarray | None = None  # unit vector from entry towards the tip
    covariance: np.ndarray | None = None  # of the tip, mm^2
    latency_ms: float = 0.0
    reason: str | None = None
    # why there is no needle on this frame (searching, lost) or why its measurement was not
    # used; None when there is nothing to explain
    axis_point_mm: np.ndarray | None = None
    # a point of the needle's axis, which runs through it along ``direction``: where the
    # visible needle starts (in-plane: its entry, or the axis at the ROI's anchor; volume: the
    # entry of the fitted segment). None without a tip, and for the axial tracker, whose
    # slices cross the axis at ``tip_mm``
    details: EstimateDetails | None = None
    # the tracker's own values (InplaneDetails, LineDetails, AxialDetails, VolumeDetails);
    # None where it has none: a frame it could not measure (a constant image, NaN pixels),
    # and the line tracker's frames without a needle

    def to_json(self) -> dict:
        """The estimate as ``needlenet track --json`` writes a frame: the fields above (reason
        and axis_point_mm only when set), then the details' keys."""
        def arr(v):
            return None if v is None else np.asarray(v, float).round(6).tolist()

        out = {"t": float(self.t), "status": self.status.value, "tip_mm": arr(self.tip_mm),
               "direction": arr(self.direction), "covariance": arr(self.covariance),
               "latency_ms": float(self.latency_ms)}
        if self.reason is not None:
            out["reason"] = self.reason
        if self.axis_point_mm is not None:
            out["axis_point_mm"] = arr(self.axis_point_mm)
        if self.details is not None:
            out.update(self.details.to_json())
        return out


RngLike = np.random.Generator | int | None


class Tracker(ABC):
    """Base class: subclasses implement :meth:`_step`; :meth:`update` adds timing and turns a
    frame that cannot be measured into a ``lost``/``searching`` report instead of a crash.

    Every tracker is built as ``Tracker(method, features, *, ..., rng=None, seed=None)``:
    ``rng`` (a generator or a seed) or ``seed`` makes its randomised parts (RANSAC samples,
    particle filters) repeat; ``self.rng`` is that generator, for every tracker alike."""

    modality: str = ""
    methods: tuple[str, ...] = ()

    def __init__(self, method: str, features: FeatureSource | None = None, *,
                 rng: RngLike = None, seed: int | None = None):
        if method not in self.methods:
            raise ValueError(f"{type(self).__name__}: unknown method {method!r}; "
                             f"choose one of {', '.join(self.methods)}")
        if rng is not None and seed is not None:
            raise ValueError(f"{type(self).__name__}: give rng or seed, not both")
        self.rng = np.random.default_rng(seed if rng is None else rng)
        self.method = method
        self.features = features if features is not None else self.default_features()
        self.status = Status.SEARCHING
        self.reset()

    @classmethod
    def default_features(cls) -> FeatureSource:
        from ..features import IntensityFeatures

        return IntensityFeatures()

    def reset(self) -> None:
        """Forget everything: the next frame starts a new detection."""
        self.status = Status.SEARCHING

    def update(self, frame: Frame) -> NeedleEstimate:
        t0 = time.perf_counter()
        try:
            check_frame(frame)
            est = self._step(zero_margins(frame))
        except FrameError as exc:
            self.status = Status.LOST if self.status == Status.TRACKING else self.status
            est = NeedleEstimate(t=frame.t, status=self.status, reason=str(exc))
        est.latency_ms = (time.perf_counter() - t0) * 1e3
        self.status = est.status
        return est

    @abstractmethod
    def _step(self, frame: Frame) -> NeedleEstimate:
        """Process one frame (already checked) and return the estimate."""

    def run(self, seq, progress=None) -> list[NeedleEstimate]:
        """Track every frame of a :class:`synth.Sequence`."""
        out = []
        for frame in frames_from_sequence(seq):
            out.append(self.update(frame))
            if progress is not None:
                progress()
        return out


def frames_from_sequence(seq):
    """Frames of a sequence; a robot's insertion-speed measurement is passed along when the
    sequence's meta records one (``meta['params']['speed_mm_s']``)."""
    grid = seq.grid()
    params = seq.meta.get("params", {}) if isinstance(seq.meta, dict) else {}
    draw = seq.meta.get("draw", {}) if isinstance(seq.meta, dict) else {}
    speed = draw.get("speed_mm_s", params.get("speed_mm_s"))
    for i in range(seq.n_frames):
        yield Frame(image=seq.images[i], grid=grid, t=float(seq.timestamps_s[i]), index=i,
                    insertion_speed_mm_s=None if speed is None else float(speed),
                    probe_pose=None if seq.probe_pose is None else seq.probe_pose[i])
