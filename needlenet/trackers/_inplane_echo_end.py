"""Where a needle's echo ends along its line in the image: a bound on a learned tip.

A learned shaft map marks a needle's line past its tip wherever the image goes on bright
along it: plane-wave and diverging-wave imaging leave a streak along a specular needle's line
past its tip, 12-25 dB below the shaft 1 mm on (measured on PyMUST's own needle, docs/notes/
inplane.md), and a map trained on other images takes it for shaft. The image itself shows
where the needle's echo drops. Along the line, the echo profile (the brightest pixel across
the line, within ``across_mm`` of it, at each step) is scanned for its largest drop: the mean
over ``window_mm`` before a point minus the mean over ``window_mm`` after it. The echo ends
there when that drop reaches ``min_drop_sd`` speckle spreads (two: about 11 dB of log-
compressed speckle, under the streak's 12-25 dB) and the echo does not come back before the
map's tip (every later window stays a spread below the level before the drop: a faded
stretch of shaft is no end). The scan covers ``back_mm`` before the map's tip (the streak's
length, up to 7 mm on a saturated shaft) to ``ahead_mm`` past it. A map's tip that lies more
than ``window_mm`` (the drop's resolution) past the echo's end is moved back to it; one
nearer is the map's own.

A needle near the skin at a few degrees shows no such drop: its echo is saturated, and so is
the streak for several millimetres, longer than ``back_mm`` with few compounded transmits;
the streak then fades over millimetres, with no step. What ends at the tip there is the
needle's reverberation tail, the copies of its echo under the shaft, which fade with the
streak's own copies. So the echo is also read as the mean over a band across the line, from
``band_mm[0]`` above it to ``band_mm[1]`` below it (the echo with its tail), and its level
over ``shaft_mm`` of shaft next to the entry (after the first ``window_mm``, where the map's
evidence starts at the edge of the view): where that mean has fallen ``band_fall_sd`` spreads
below the shaft's level by the map's tip, the echo ends where it last stood within one spread
of that level (the start of the fall, not its steepest point), provided the echo line itself
goes on there within ``min_drop_sd`` spreads of its own level on the shaft (a streak; a needle
leaving the plane fades as a whole). The earlier of the two ends is taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..features import Frame
from ._inplane_line_echo import frame_float32, frame_spread, image_strip

__all__ = ["EchoEndParams", "echo_end"]


@dataclass(frozen=True)
class EchoEndParams:
    """See the module's doc (distances in mm along the needle's line). ``band_fall_sd``: the
    band's mean averages a few hundred pixels, so its own noise is a fraction of a speckle
    spread, and layers of tissue differ by up to about one spread (``tissue_level`` in
    :mod:`._inplane_line_echo`): a fall of one and a half spreads is more than a change of
    layer, where the echo line's single profile needs ``min_drop_sd``."""

    window_mm: float = 1.5
    across_mm: float = 0.5
    min_drop_sd: float = 2.0
    band_fall_sd: float = 1.5
    back_mm: float = 6.0
    ahead_mm: float = 1.0
    band_mm: tuple[float, float] = (-0.5, 3.0)
    shaft_mm: float = 4.0

    def __post_init__(self) -> None:
        lengths = (self.window_mm, self.across_mm, self.back_mm, self.ahead_mm, self.shaft_mm,
                   *self.band_mm)
        if not (self.window_mm > 0 and self.across_mm >= 0 and self.min_drop_sd > 0
                and self.band_fall_sd > 0
                and self.back_mm > 0 and self.ahead_mm >= 0 and self.shaft_mm > 0
                and self.band_mm[0] < self.band_mm[1]
                and all(abs(v) <= 100.0 for v in lengths)):  # a fraction of any image
            raise ValueError(f"echo end settings out of range: {self}")


def echo_end(frame: Frame, start_mm: np.ndarray, direction: np.ndarray, tip_along_mm: float,
             params: EchoEndParams) -> float | None:
    """Where (mm along ``direction`` from ``start_mm``, the needle's entry end) the needle's
    echo ends, when a tip at ``tip_along_mm`` lies more than ``params.window_mm`` past it;
    None when the tip stands (no end seen, or the tip within the drop's resolution). The
    earlier of the echo's drop and the fall of its band (see the module's doc)."""
    ends = [e for e in (_largest_drop(frame, start_mm, direction, tip_along_mm, params),
                        _band_fall(frame, start_mm, direction, tip_along_mm, params))
            if e is not None]
    return min(ends) if ends else None


def _means(profile: np.ndarray, k: int) -> np.ndarray:
    """Means over ``k`` samples: element m covers samples m .. m + k - 1."""
    c = np.concatenate([[0.0], np.cumsum(profile)])
    return (c[k:] - c[:-k]) / k


def _largest_drop(frame: Frame, start_mm: np.ndarray, direction: np.ndarray,
                  tip_along_mm: float, p: EchoEndParams) -> float | None:
    """The echo's largest drop before the map's tip, when it reaches ``min_drop_sd`` spreads
    and the echo does not come back."""
    step = float(min(frame.grid.spacing_mm))
    k = max(int(round(p.window_mm / step)), 1)
    lo = max(tip_along_mm - p.back_mm, p.window_mm)
    t = np.arange(lo - p.window_mm, tip_along_mm + p.ahead_mm + p.window_mm + 1e-9, step)
    if len(t) < 2 * k + 1:
        return None
    d = np.asarray(direction, float)
    across = np.arange(-p.across_mm, p.across_mm + 1e-9, step)
    image = frame_float32(frame)
    profile = image_strip(image, frame, np.asarray(start_mm, float), d,
                          np.array([-d[1], d[0]]), t, across).max(axis=0)
    means = _means(profile, k)
    at = np.arange(k, len(profile) - k + 1)  # a drop between t[i - 1] and t[i]
    drop = means[at - k] - means[at]
    j = int(np.argmax(drop))
    spread = frame_spread(frame)
    end = float(t[at[j]])
    if drop[j] < p.min_drop_sd * spread or tip_along_mm - end <= p.window_mm:
        return None
    later = means[at[j]:int(np.searchsorted(t, tip_along_mm))]
    if later.size and later.max() > means[at[j] - k] - spread:
        return None  # the echo comes back: a faded stretch of shaft
    return end


def _band_fall(frame: Frame, start_mm: np.ndarray, direction: np.ndarray,
               tip_along_mm: float, p: EchoEndParams) -> float | None:
    """Where the mean over the band across the line (the echo with its reverberation tail)
    last stood within a spread of the shaft's level next to the entry, when by the map's tip
    it has fallen ``band_fall_sd`` spreads below it."""
    step = float(min(frame.grid.spacing_mm))
    k = max(int(round(p.window_mm / step)), 1)
    shaft_to = p.window_mm + p.shaft_mm
    if tip_along_mm - shaft_to < 2 * p.window_mm:
        return None  # too short a segment to read the shaft's level and a fall after it
    t = np.arange(p.window_mm, tip_along_mm + 1e-9, step)
    d = np.asarray(direction, float)
    down = np.array([-d[1], d[0]]) if d[0] >= 0 else np.array([d[1], -d[0]])  # z grows
    across = np.arange(p.band_mm[0], p.band_mm[1] + 1e-9, step)
    image = frame_float32(frame)
    strip = image_strip(image, frame, np.asarray(start_mm, float), d, down, t, across)
    profile = strip.mean(axis=0)
    shaft = t <= shaft_to
    level = float(np.median(profile[shaft]))
    spread = frame_spread(frame)
    trailing = _means(profile, k)  # element m ends at t[m + k - 1]
    if trailing[-1] > level - p.band_fall_sd * spread:
        return None  # by the map's tip the band has not fallen: no end seen
    within = np.flatnonzero(trailing >= level - spread)
    if not within.size:
        return None
    m = within[-1] + k - 1
    end = float(t[m])
    if tip_along_mm - end <= p.window_mm:
        return None
    # the echo line itself goes on as bright past there (a streak): a needle's echo that
    # fades as a whole, leaving the plane, fades with its band and is no streak
    line = strip[np.abs(across) <= p.across_mm].max(axis=0)
    if line[m + 1:m + 1 + k].mean() < float(np.median(line[shaft])) - p.min_drop_sd * spread:
        return None
    return end
