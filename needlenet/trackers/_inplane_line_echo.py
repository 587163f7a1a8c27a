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

The test's premise is tissue above the line. Where the band above is anechoic (a vessel's
lumen, a shadow), any tissue below it reads as echo: the bottom of a vessel is a step, not a
needle. A section whose band lies more than ``anechoic_sd`` speckle spreads below the tissue's
level at its depth (:func:`tissue_level`) is therefore no evidence either way: it is left out
of the share, and past a line's end it shows no end of the echo (:func:`echo_beyond`). A
needle under a vessel is seen by its sections elsewhere; a step whose every section lies under
the lumen is no needle.

A needle's tip is where its echo ends, so the same sections are read on past the segment's
end (:func:`echo_beyond`): where the echo goes on, the tip lies further on, and where it goes
on to the edge of the view the line shows no tip at all (a tissue interface, or a needle whose
tip has left the view).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from .._sampling import remap_points
from ..backends import NeedleLine
from ..features import (
    Frame,
    TipFeatures,  # Mathiassen's echo test, shared
    frame_image_statistics,
)
from ._inplane_evidence import echo_sections, echo_shown, section_means

__all__ = ["EchoTestParams", "echo_along", "echo_beyond", "frame_float32", "frame_spread",
           "image_strip", "tissue_level"]


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
    lines, read up to 40 mm past their end). ``anechoic_sd``: a band this many speckle
    spreads below the tissue's level is no tissue (the mean of a band 1.9 x 1 mm averages
    over some 20 speckle cells, so tissue's band means stay within about a quarter of a
    spread of its level, and layers of tissue within about one). ``level_window_mm``: the
    depth range (each side) over which that level is the median."""

    line_half_width_mm: float = 0.2
    band_mm: tuple[float, float] = (2.0, 3.0)
    null_up_mm: float = 1.4
    section_mm: float = 1.9
    z: float = 2.0
    coverage: float = 0.5
    beyond_z: float = 3.5
    anechoic_sd: float = 2.0
    level_window_mm: float = 5.0

    def __post_init__(self) -> None:
        lo, hi = self.band_mm
        if not (self.line_half_width_mm > 0 and 0 < lo < hi and self.null_up_mm > 0
                and self.section_mm > 0 and self.z > 0 and 0 < self.coverage <= 1
                and self.beyond_z > 0 and self.anechoic_sd > 0 and self.level_window_mm > 0):
            raise ValueError(f"echo test settings out of range: {self}")


def image_strip(image: np.ndarray, frame: Frame, start: np.ndarray, d: np.ndarray,
                up: np.ndarray, t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The image on points start + t d + y up: rows y, columns t."""
    (oz, ox), (dz, dx) = frame.grid.origin_mm, frame.grid.spacing_mm
    # each coordinate on its own (Grid.points_to_index's arithmetic, without (N, 2) arrays)
    cols = ((start[0] + t[None, :] * d[0]) + y[:, None] * up[0] - ox) / dx
    rows = ((start[1] + t[None, :] * d[1]) + y[:, None] * up[1] - oz) / dz
    return remap_points(image, cols, rows, cv2.BORDER_REPLICATE).astype(np.float64)


def _row_medians(image: np.ndarray) -> np.ndarray:
    """Each row's median imaged (non-zero) pixel, NaN for a row without one (the lower middle
    value for an even count); from one histogram per row for 8-bit frames. Rows wider than
    256 pixels are read on every other column."""
    if image.shape[1] > 256:
        image = image[:, ::2]
    if image.dtype == np.uint8:
        return _row_medians_u8(image)
    h, w = image.shape
    imaged = np.count_nonzero(image, axis=1)
    rows = np.sort(np.where(image > 0, image, np.inf).astype(np.float64), axis=1)
    med = rows[np.arange(h), np.clip((imaged - 1) // 2, 0, w - 1)]
    return np.where(imaged > 0, med, np.nan)


@numba.njit(cache=True, nogil=True)
def _row_medians_u8(image):  # pragma: no cover - compiled
    """:func:`_row_medians` of an 8-bit image: each row's histogram of its non-zero pixels,
    and the first grey level whose cumulative count reaches the lower middle rank."""
    h, w = image.shape
    out = np.full(h, np.nan)
    counts = np.zeros(256, np.int64)
    for r in range(h):
        counts[:] = 0
        n = 0
        for c in range(w):
            v = image[r, c]
            if v != 0:
                counts[v] += 1
                n += 1
        if n == 0:
            continue
        rank = (n - 1) // 2 + 1
        total = 0
        for v in range(256):
            total += counts[v]
            if total >= rank:
                out[r] = v
                break
    return out


def frame_float32(frame: Frame) -> np.ndarray:
    """The frame's image as float32, converted once per frame: the echo tests read it several
    times a frame (1 ms a conversion of a 1200 x 960 frame)."""
    if "image_float32" not in frame.extras:
        frame.extras["image_float32"] = np.asarray(frame.image, np.float32)
    return frame.extras["image_float32"]


def frame_spread(frame: Frame) -> float:
    """The frame's speckle spread: 1.4826 times the median absolute deviation of its imaged
    pixels (as for :func:`~needlenet.features.line_contrast`). Read once per frame."""
    return frame_image_statistics(frame)[1]


def tissue_level(frame: Frame, window_mm: float) -> tuple[np.ndarray, float]:
    """The tissue's grey level at each image row (the median, over the imaged rows within
    ``window_mm`` of it, of each row's median imaged pixel: local in depth, where gain and
    attenuation change the level, and robust to a vessel or shadow that covers less than half
    a row) and the frame's speckle spread (:func:`frame_spread`). Read once per frame."""
    key = ("tissue_level", float(window_mm))
    if key not in frame.extras:
        im = np.asarray(frame.image)
        med = _row_medians(im)
        level = np.full(len(med), np.nan)
        rows = np.flatnonzero(np.isfinite(med))
        if rows.size:
            k = max(int(round(window_mm / float(frame.grid.spacing_mm[0]))), 0)
            pad = np.pad(med[rows], k, mode="edge")
            # every 4th row of the window: neighbouring rows share their speckle
            windows = np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1)[:, ::4]
            level[rows] = np.median(windows, axis=1)
            # rows without imaged pixels (a capture margin) take the nearest imaged row's
            level = np.interp(np.arange(len(med)), rows, level[rows])
        frame.extras[key] = (level, frame_spread(frame))
    return frame.extras[key]


def _section_z(frame: Frame, start: np.ndarray, d: np.ndarray, length_mm: float,
               from_mm: float, p: EchoTestParams) -> np.ndarray:
    """z of each section from ``from_mm`` on, of the line read from ``start`` along ``d`` for
    ``length_mm`` (the noise measured over the whole line); NaN where the band above is
    anechoic (see the module's doc); empty when that is under two samples."""
    image = frame_float32(frame)
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
    s = image_strip(image, frame, start, d, up, t, y)
    a, b = len(line_y), len(band_y)
    null = s[a + b:2 * a + b].mean(0) - s[2 * a + b:].mean(0)
    band = s[a:a + b].mean(0)
    feats = TipFeatures(t, None, s[:a].mean(0), band, s[a:a + b].std(0), null)
    n = _section_samples(step, p)
    z = echo_sections(feats, from_mm, float(t[-1]), n)
    level, spread = tissue_level(frame, p.level_window_mm)
    centre = start[None] + t[:, None] * d[None] + band_y.mean() * up[None]
    row = np.clip(np.rint(frame.grid.points_to_index(centre)[:, 0]).astype(int), 0,
                  len(level) - 1)
    with np.errstate(invalid="ignore"):
        dark = (band < level[row] - p.anechoic_sd * spread).astype(np.float64)
    if z.size:
        anechoic = section_means(dark[t >= from_mm], n) > 0.5
        z = np.where(anechoic, np.nan, z)
    return z


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
    ``params.beyond_z``. Sections that are no evidence (their band above anechoic: a lumen,
    or the black outside a sector) do not show where the echo ends: a run followed only by
    such sections to the end of the read, or a read of such sections alone, is taken to go
    on to its end (no end of the echo is seen)."""
    step = float(min(frame.grid.spacing_mm))
    if reach_mm < params.section_mm:
        return 0.0
    d = seg.direction if entry_first else -seg.direction
    start = seg.start_mm if entry_first else seg.end_mm
    z = _section_z(frame, start, d, seg.length_mm + reach_mm, seg.length_mm, params)
    if not z.size:
        return 0.0
    read = np.flatnonzero(np.isfinite(z))
    if not read.size:
        return float(reach_mm)  # nothing past the end can be read: no end seen
    k = np.arange(1, len(z) + 1)
    glr = np.cumsum(np.nan_to_num(z, nan=0.0)) / np.sqrt(k)
    best = int(np.argmax(glr))
    if glr[best] < params.beyond_z:
        return 0.0
    if best >= read[-1] and read[-1] + 1 < len(z):
        return float(reach_mm)  # echo up to where the read ends: it goes on that far
    section = _section_samples(step, params) * step
    return float(min(k[best] * section, reach_mm))
