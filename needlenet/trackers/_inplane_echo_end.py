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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..features import Frame
from ._inplane_line_echo import frame_spread, image_strip

__all__ = ["EchoEndParams", "echo_end"]


@dataclass(frozen=True)
class EchoEndParams:
    """See the module's doc (distances in mm along the needle's line)."""

    window_mm: float = 1.5
    across_mm: float = 0.5
    min_drop_sd: float = 2.0
    back_mm: float = 6.0
    ahead_mm: float = 1.0

    def __post_init__(self) -> None:
        if not (self.window_mm > 0 and self.across_mm >= 0 and self.min_drop_sd > 0
                and self.back_mm > 0 and self.ahead_mm >= 0):
            raise ValueError(f"echo end settings out of range: {self}")


def echo_end(frame: Frame, start_mm: np.ndarray, direction: np.ndarray, tip_along_mm: float,
             params: EchoEndParams) -> float | None:
    """Where (mm along ``direction`` from ``start_mm``, the needle's entry end) the needle's
    echo ends, when a tip at ``tip_along_mm`` lies more than ``params.window_mm`` past it;
    None when the tip stands (no drop, or the tip within the drop's resolution)."""
    p = params
    step = float(min(frame.grid.spacing_mm))
    k = max(int(round(p.window_mm / step)), 1)
    lo = max(tip_along_mm - p.back_mm, p.window_mm)
    t = np.arange(lo - p.window_mm, tip_along_mm + p.ahead_mm + p.window_mm + 1e-9, step)
    if len(t) < 2 * k + 1:
        return None
    d = np.asarray(direction, float)
    across = np.arange(-p.across_mm, p.across_mm + 1e-9, step)
    image = np.asarray(frame.image, np.float32)
    profile = image_strip(image, frame, np.asarray(start_mm, float), d,
                          np.array([-d[1], d[0]]), t, across).max(axis=0)
    c = np.concatenate([[0.0], np.cumsum(profile)])
    means = (c[k:] - c[:-k]) / k  # means[m]: the window t[m] .. t[m + k - 1]
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
