"""Whether Mathiassen 2017's in-plane tracker sees a needle along an axis on one frame.

The paper switches its methods on once about 10 mm of needle is in view (sections II and
V-A) and says nothing of frames without one; a tracker that feeds a probe servo must tell them
apart. A straight needle in the image plane shows its line echo along its whole visible
length: that is the assumption behind Algorithm 1's histogram ("the needle will have a high
score on approximately the same position along v_p for all the rays, while other nonneedle
structures will be distributed on different positions"). So the needle is taken as seen only
where its echo shows along the axis from the first ray to the tip, not just on average over
it:

- learned source: the shaft probability on the line averages at least ``learned_level`` (the
  map's decision level; a clean map is near 0 or 1, so this asks that about half the axis be
  marked);
- classical source: the axis is cut into sections of 2s+1 samples, the length over which
  eq. (1) averages a ray. In each section the line echo's mean minus the mean of the tissue
  band above it is compared with the noise of that same difference on tissue, measured on the
  same frame: the difference between the same pair of rows moved further up, away from the
  echo (tissue both), whose spread over every section of the axis (1.4826 times the median
  absolute deviation) is that of a line-minus-band difference where no line is. A section shows
  the echo when it stands ``echo_z`` noise SDs above 0, and the needle is seen when at least
  ``echo_coverage`` of the sections show it, both over the whole axis and over its first half:
  the paper's needle enters the image at the ROI's corner, where the axis starts, and its
  shaft is echogenic from there on, so its echo is not confined to the far part of the axis.
  Speckle that happens to be brightest along one line shows in few sections; a tissue line
  lying further along a tracked axis misses the entry half.
"""

from __future__ import annotations

import numpy as np

from ..features import TipFeatures

__all__ = ["echo_sections", "echo_shown", "section_means", "classical_echo_seen",
           "learned_level_reached"]


def section_means(values: np.ndarray, n: int) -> np.ndarray:
    """Means of consecutive runs of ``n`` samples along the last axis (a shorter rest dropped
    unless it is all there is)."""
    m = values.shape[-1] // n
    if m == 0:
        return values.mean(axis=-1, keepdims=True)
    return values[..., :m * n].reshape(values.shape[:-1] + (m, n)).mean(axis=-1)


def echo_sections(feats: TipFeatures, x_from_mm: float, x_to_mm: float,
                  section_samples: int) -> np.ndarray:
    """z of each section of ``section_samples`` samples of the axis within [x_from, x_to]: the
    line echo's mean minus the tissue band's, over the noise of that difference on tissue (see
    the module's doc). Empty when the range holds no sample or the source has no null."""
    if feats.null_difference is None:
        return np.zeros(0)
    n = max(int(section_samples), 1)
    null = section_means(feats.null_difference, n)
    sd = 1.4826 * float(np.median(np.abs(null - np.median(null))))
    sel = (feats.x_mm >= x_from_mm) & (feats.x_mm <= x_to_mm)
    if not sel.any():
        return np.zeros(0)
    diff = section_means(feats.line[sel] - feats.background[sel], n)
    return diff / max(sd, 1e-9)


def classical_echo_seen(feats: TipFeatures, x_from_mm: float, x_to_mm: float,
                        section_samples: int, z_min: float, coverage: float
                        ) -> tuple[bool, float]:
    """Whether the echo shows along [x_from, x_to]: at least ``coverage`` of its sections at
    ``z_min`` noise SDs, over the whole range and over its first half (the entry's); and the
    share of all sections that show it (0 when there is none)."""
    return echo_shown(echo_sections(feats, x_from_mm, x_to_mm, section_samples), z_min,
                      coverage)


def echo_shown(z: np.ndarray, z_min: float, coverage: float) -> tuple[bool, float]:
    """Whether sections of z ``z`` show the echo (at least ``coverage`` of them at ``z_min``,
    over all and over the first half), and the share that do (0 when there are none). NaN
    sections are no evidence either way: left out of both shares (all NaN: not shown)."""
    counted = np.isfinite(z)
    if not counted.any():
        return False, 0.0
    shows = z >= z_min
    share = float(shows[counted].mean())
    first = slice(0, max(1, (len(z) + 1) // 2))
    entry = counted[first]
    entry_half = float(shows[first][entry].mean()) if entry.any() else 0.0
    return bool(share >= coverage and entry_half >= coverage), share


def learned_level_reached(feats: TipFeatures, x_from_mm: float, x_to_mm: float,
                          level: float) -> bool:
    """Whether a learned shaft map averages at least ``level`` on the line in [x_from, x_to]."""
    sel = (feats.x_mm >= x_from_mm) & (feats.x_mm <= x_to_mm)
    return bool(sel.any()) and float(feats.line[sel].mean()) >= level
