"""Whether a line found on a classical feature map shows a needle's echo along its length.

The classical map of the `line` tracker (:func:`~needlenet.features.line_contrast`) marks
any ridge that stands out of its surroundings, and speckle or a short tissue line does so in
places. A needle's specular wall echoes along its whole visible length, so the same test as
for Mathiassen's methods with classical features (:mod:`._inplane_evidence`) decides: the
image is read on a strip along the segment; the segment is cut into sections of the length
over which Mathiassen's eq. (1) averages a ray (2s+1 samples, 1.9 mm); in each, the mean of
the line echo minus the mean of the tissue band above it (towards the probe, away from the
reverberations and the shadow below) is compared with the noise of that same difference on
tissue, measured on the same frame with both rows moved further up. The echo shows along the
segment when at least ``coverage`` of its sections stand ``z`` noise SDs out, over the whole
segment and over its entry half (the shaft is echogenic from the entry on).

A needle's tip is where its echo ends, so the same sections are read on past the segment's
end (:func:`echo_beyond`): where the echo goes on, the tip lies further on, and where it goes
on to the edge of the view the line shows no tip at all (a tissue interface, or a needle whose
tip has left the view).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..backends import NeedleLine
from ..features import (
    Frame,
    TipFeatures,  # Mathiassen's echo test, shared
)
from ._inplane_evidence import echo_sections, echo_shown

__all__ = ["EchoTestParams", "echo_along", "echo_beyond"]


@dataclass(frozen=True)
class EchoTestParams:
    """The echo test of a classical line (the values of Mathiassen's methods, so both kinds
    of tracker judge an echo alike). ``line_half_width_mm``: half-width of the line echo
    read; ``band_mm``: the tissue band above it (distances towards the probe); ``null_up_mm``:
    how far both are moved up to measure the difference where no line is; ``section_mm``: the
    length of a section (2s+1 samples of Mathiassen's eq. 1, s = 0.9 mm); ``z``: noise SDs at
    which a section shows the echo; ``coverage``: the share of sections that must show it;
    ``beyond_z``: the level at which the echo is taken to go on past a line's end
    (:func:`echo_beyond`; 3: a run that long arises from tissue alone on about 1% of
    lines, read up to 40 mm past their end)."""

    line_half_width_mm: float = 0.2
    band_mm: tuple[float, float] = (2.0, 3.0)
    null_up_mm: float = 1.4
    section_mm: float = 1.9
    z: float = 2.0
    coverage: float = 0.5
    beyond_z: float = 3.5

    def __post_init__(self) -> None:
        lo, hi = self.band_mm
        if not (self.line_half_width_mm > 0 and 0 < lo < hi and self.null_up_mm > 0
                and self.section_mm > 0 and self.z > 0 and 0 < self.coverage <= 1
                and self.beyond_z > 0):
            raise ValueError(f"echo test settings out of range: {self}")


def _strip(image: np.ndarray, frame: Frame, start: np.ndarray, d: np.ndarray,
           up: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The image on points start + t d + y up: rows y, columns t."""
    pts = start[None, None] + t[None, :, None] * d[None, None] + y[:, None, None] * up[None, None]
    idx = frame.grid.points_to_index(pts.reshape(-1, 2))
    out = cv2.remap(image, idx[:, 1].astype(np.float32).reshape(1, -1),
                    idx[:, 0].astype(np.float32).reshape(1, -1), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(len(y), len(t)).astype(np.float64)


def _section_z(frame: Frame, start: np.ndarray, d: np.ndarray, length_mm: float,
               from_mm: float, p: EchoTestParams) -> np.ndarray:
    """z of each section from ``from_mm`` on, of the line read from ``start`` along ``d`` for
    ``length_mm`` (the noise measured over the whole line); empty when that is under two
    samples."""
    image = np.asarray(frame.image, np.float32)
    step = float(min(frame.grid.spacing_mm))
    n = np.array([-d[1], d[0]])
    up = n if n[1] < 0 or (n[1] == 0 and n[0] < 0) else -n  # towards the probe (shallower)
    t = np.arange(0.0, length_mm + 1e-9, step)
    if len(t) < 2:
        return np.zeros(0)
    k = max(int(round(p.line_half_width_mm / step)), 0)
    line_y = step * np.arange(-k, k + 1)
    band_y = np.arange(p.band_mm[0], p.band_mm[1] + 1e-9, step)
    y = np.concatenate([line_y, band_y, line_y + p.null_up_mm, band_y + p.null_up_mm])
    s = _strip(image, frame, start, d, up, t, y)
    a, b = len(line_y), len(band_y)
    null = s[a + b:2 * a + b].mean(0) - s[2 * a + b:].mean(0)
    feats = TipFeatures(t, None, s[:a].mean(0), s[a:a + b].mean(0), s[a:a + b].std(0), null)
    return echo_sections(feats, from_mm, float(t[-1]), _section_samples(step, p))


def _section_samples(step_mm: float, p: EchoTestParams) -> int:
    return max(int(round(p.section_mm / step_mm)), 1)


def echo_along(frame: Frame, seg: NeedleLine, entry_first: bool,
               params: EchoTestParams) -> tuple[bool, float]:
    """Whether the needle's echo shows along ``seg`` on ``frame``'s image (see the module's
    doc), and the share of its sections that show it. ``entry_first``: the segment's start is
    its entry end."""
    d = seg.direction if entry_first else -seg.direction
    start = seg.start_mm if entry_first else seg.end_mm
    z = _section_z(frame, start, d, seg.length_mm, 0.0, params)
    return echo_shown(z, params.z, params.coverage)


def echo_beyond(frame: Frame, seg: NeedleLine, entry_first: bool, reach_mm: float,
                params: EchoTestParams) -> float:
    """How far (mm) the echo goes on past ``seg``'s tip end, read for up to ``reach_mm``:
    0 unless it shows there. A line found on the classical map can stop short of its echo's
    end where the tissue around changes (a needle crossing an interface into brighter tissue
    loses contrast on the map, not in its echo), and a short piece of a long interface looks
    like a needle. The sections past the end (their z as in :func:`echo_along`, the noise
    measured along segment and continuation together) are scanned for where a run of echo
    ends: k sections go on when the sum of their z over the root of k, the generalised
    likelihood ratio of a mean shift over the first k, is largest there and reaches
    ``params.beyond_z``."""
    step = float(min(frame.grid.spacing_mm))
    if reach_mm < params.section_mm:
        return 0.0
    d = seg.direction if entry_first else -seg.direction
    start = seg.start_mm if entry_first else seg.end_mm
    z = _section_z(frame, start, d, seg.length_mm + reach_mm, seg.length_mm, params)
    if not z.size:
        return 0.0
    k = np.arange(1, len(z) + 1)
    glr = np.cumsum(z) / np.sqrt(k)
    best = int(np.argmax(glr))
    if glr[best] < params.beyond_z:
        return 0.0
    section = _section_samples(step, params) * step
    return float(min(k[best] * section, reach_mm))
