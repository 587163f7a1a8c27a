"""The classical line tracker's echo test (needlenet/trackers/_inplane_line_echo.py): a line
counts as a needle only where its echo stands out of the tissue along it."""

import numpy as np
import pytest

import synth
from needlenet.backends import NeedleLine
from needlenet.features import Frame
from needlenet.trackers._inplane_line_echo import (
    EchoTestParams,
    echo_along,
    echo_beyond,
    tissue_level,
)

SPACING = 0.1


def _speckle(seed: int, shape=(300, 300)) -> np.ndarray:
    """Log-compressed fully developed speckle (Rayleigh envelope), 8-bit."""
    rng = np.random.default_rng(seed)
    env = np.abs(rng.normal(size=shape) + 1j * rng.normal(size=shape))
    return np.clip(40 * np.log10(env + 1e-3) + 110, 0, 255)


def _frame(image: np.ndarray) -> Frame:
    g = synth.Grid(image.shape, (SPACING, SPACING), (0.0, 0.0))
    return Frame(image=image.astype(np.uint8), grid=g)


def _segment(a, b) -> NeedleLine:
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    return NeedleLine(True, "", a, b, d, 1.0, 1.0)


def _draw(image, a, b, value, frac=(0.0, 1.0)):
    """A 0.3 mm thick line from a to b (mm) at ``value``, over the fraction ``frac`` of it."""
    t = np.linspace(*frac, 2000)[:, None]
    p = np.asarray(a) + t * (np.subtract(b, a))
    for off in (-1, 0, 1):
        r = np.clip(np.rint(p[:, 1] / SPACING).astype(int) + off, 0, image.shape[0] - 1)
        c = np.clip(np.rint(p[:, 0] / SPACING).astype(int), 0, image.shape[1] - 1)
        image[r, c] = value
    return image


A, B = (2.0, 8.0), (27.0, 22.0)  # entry (shallower) end first


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_bright_line_shows_its_echo(seed):
    im = _draw(_speckle(seed), A, B, 250)
    seen, share = echo_along(_frame(im), _segment(A, B), True, EchoTestParams())
    assert seen and share > 0.9


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_speckle_along_a_line_does_not(seed):
    seen, share = echo_along(_frame(_speckle(seed)), _segment(A, B), True, EchoTestParams())
    assert not seen and share < 0.3


def test_a_line_bright_only_beyond_its_entry_half_does_not():
    """A tissue line further along the segment than its entry half: the needle's shaft would
    be echogenic from the entry on."""
    im = _draw(_speckle(3), A, B, 250, frac=(0.4, 1.0))
    seen, share = echo_along(_frame(im), _segment(A, B), True, EchoTestParams())
    assert not seen and 0.5 <= share < 0.75
    # read from the other end, the bright half is the entry half
    assert echo_along(_frame(im), _segment(A, B), False, EchoTestParams())[0]


def _beyond(image, a, b, reach_mm):
    return echo_beyond(_frame(image), _segment(a, b), True, reach_mm, EchoTestParams())


def test_the_echo_read_past_the_end_of_a_line_that_goes_on():
    """A line found over the first 40% of a longer echo: its echo goes on for the other 60%
    (15 mm of the 25 mm x run, 17.6 mm along it), resolved to a section (1.9 mm)."""
    end = np.add(A, 0.4 * np.subtract(B, A))
    im = _draw(_speckle(4), A, B, 250)
    rest = 0.6 * float(np.hypot(*np.subtract(B, A)))
    more = _beyond(im, A, end, reach_mm=rest + 4.0)
    assert rest - 1.9 <= more <= rest + 1.9
    # read for 8 mm only: echo all the way, to the last whole section
    assert _beyond(im, A, end, reach_mm=8.0) == pytest.approx(8.0, abs=1.9)


def test_an_echo_read_on_into_no_evidence_goes_on_as_far_as_it_is_read():
    """Past the run of echo the band above the line lies in the black outside a sector (no
    evidence) to the end of the read: the echo is taken to go on that far, not to end where
    it can no longer be read (a line along a sector's edge reaches the edge of the view)."""
    end = np.add(A, 0.4 * np.subtract(B, A))
    im = _draw(_speckle(4), A, B, 250)
    length = float(np.hypot(*np.subtract(B, A)))
    d = np.subtract(B, A) / length
    up = np.array([d[1], -d[0]])  # towards the probe
    z, x = np.mgrid[:im.shape[0], :im.shape[1]] * SPACING
    along = (x - A[0]) * d[0] + (z - A[1]) * d[1]
    above = (x - A[0]) * up[0] + (z - A[1]) * up[1]
    im[(along > 0.75 * length) & (above > 0.5)] = 0
    rest = 0.6 * length
    assert _beyond(im, A, end, reach_mm=rest) == pytest.approx(rest)


def test_no_echo_past_the_end_of_a_line_that_ends():
    end = np.add(A, 0.4 * np.subtract(B, A))
    im = _draw(_speckle(5), A, B, 250, frac=(0.0, 0.4))
    assert _beyond(im, A, end, reach_mm=15.0) == 0.0
    assert _beyond(im, A, end, reach_mm=1.0) == 0.0  # less than a section: nothing read


def test_speckle_past_a_line_rarely_reads_as_echo():
    """The scan's level (3.5) is reached on tissue alone about 0.2% of the time for 20
    independent sections with a known noise; here the noise is measured along the same 35
    mm of line (as the tracker reads on to the edge of the view), so allow 2 in 200 lines
    (seeded; measured 1). Read for 15 mm only, the noise rests on fewer sections and the
    scan fires on 9 of these 200."""
    rng = np.random.default_rng(6)
    hits = 0
    for k in range(10):
        im = _speckle(100 + k, (500, 500))
        for _ in range(20):
            a = rng.uniform(2.0, 8.0, 2)
            ang = rng.uniform(0.2, 1.3)
            b = a + 5.0 * np.array([np.cos(ang), np.sin(ang)])
            hits += _beyond(im, a, b, reach_mm=30.0) > 0
    assert hits <= 2, f"{hits} of 200"


def _lumen(image, centre_mm, radius_mm):
    """An anechoic disc (a vessel across the plane): no scatterers, the display's floor."""
    z, x = np.mgrid[:image.shape[0], :image.shape[1]] * SPACING
    image[(x - centre_mm[0]) ** 2 + (z - centre_mm[1]) ** 2 < radius_mm**2] = 3
    return image


FLAT_A, FLAT_B = (3.0, 12.0), (9.0, 12.6)  # 6 mm at 6 degrees, just under a vessel


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tissue_under_a_vessel_is_no_echo(seed):
    """The tissue just below an anechoic lumen stands out of the band above it (the lumen)
    as a needle's echo stands out of tissue; with the lumen above every section it is no
    evidence (without that rule the step read as echo in every section)."""
    im = _lumen(_speckle(seed), (6.0, 9.0), 3.0)
    seen, share = echo_along(_frame(im), _segment(FLAT_A, FLAT_B), True, EchoTestParams())
    assert not seen and share == 0.0
    # read on past a line's end under the lumen alone, the echo shows no end: it is taken to
    # go on as far as it is read (a needle's tip is only where its echo is seen to end)
    assert echo_beyond(_frame(im), _segment((0.5, 11.8), (3.0, 12.0)), True, 6.0,
                       EchoTestParams()) == 6.0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_needle_partly_under_a_vessel_still_shows_its_echo(seed):
    """A needle passing under a vessel: the sections under the lumen are left out, the rest
    show its echo."""
    im = _lumen(_draw(_speckle(seed), A, B, 250), (8.0, 8.0), 2.5)
    seen, share = echo_along(_frame(im), _segment(A, B), True, EchoTestParams())
    assert seen and share > 0.9


def test_tissue_level_follows_depth_not_a_vessel():
    """The level is the tissue's median grey at each depth: a gain ramp with depth moves it;
    a vessel 10 mm wide in a 30 mm row lowers it by under half a speckle spread (the median
    of the rest of the row), far from the two spreads that mark a band anechoic."""
    ramp = np.linspace(-20.0, 20.0, 300)[:, None]
    im = np.clip(_speckle(7) + ramp, 0, 255)
    level, spread = tissue_level(_frame(im), 5.0)
    rows = np.median(im.astype(np.uint8), axis=1)
    assert np.max(np.abs(level[60:240] - rows[60:240])) < 0.2 * spread  # rows: noisier
    assert level[240] - level[60] == pytest.approx(40 * 180 / 299, abs=0.1 * spread)
    assert 15 < spread < 30  # log-compressed speckle at 40 grey levels a decade, less clipping
    vessel = _frame(_lumen(im.copy(), (15.0, 15.0), 5.0))
    lowered = level - tissue_level(vessel, 5.0)[0]
    assert 0 < np.max(lowered) < 0.5 * spread


def test_settings_out_of_range_are_refused():
    with pytest.raises(ValueError, match="echo test"):
        EchoTestParams(band_mm=(3.0, 2.0))
    with pytest.raises(ValueError, match="echo test"):
        EchoTestParams(anechoic_sd=0.0)


@pytest.mark.parametrize("seed", range(6))
def test_row_medians_are_each_rows_lower_middle_imaged_pixel(seed):
    from needlenet.trackers._inplane_line_echo import _row_medians

    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 300, 2)
    image = rng.integers(0, 256 if seed % 2 else 5, (h, w)).astype(np.uint8)
    image[:, : w // 3] = 0  # a black margin: not imaged
    image[rng.integers(0, h)] = 0  # a row without an imaged pixel
    read = image[:, ::2] if w > 256 else image
    want = np.array([np.sort(r[r > 0])[(np.count_nonzero(r) - 1) // 2] if r.any() else np.nan
                     for r in read], float)
    np.testing.assert_array_equal(_row_medians(image), want)
    np.testing.assert_array_equal(_row_medians(image.astype(np.float32)), want)
