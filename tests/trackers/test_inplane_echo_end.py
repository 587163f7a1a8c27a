"""Where a needle's echo ends along its line (needlenet/trackers/_inplane_echo_end.py): a
learned tip past it (a map that marks the streak of unfocused imaging) is moved back, to the
echo's drop or, on a saturated needle, to where its reverberation tail ends."""

import numpy as np
import pytest

from needlenet.trackers._inplane_echo_end import EchoEndParams, _band_fall, echo_end
from tests.trackers.test_inplane_line_echo import SPACING, _draw, _frame, _speckle

A = np.array([2.0, 4.0])
D = np.array([np.cos(np.deg2rad(25.0)), np.sin(np.deg2rad(25.0))])
END = 15.0  # mm along D from A, where the needle's echo ends


def _needle(seed, *, streak=None, gap=None):
    """Speckle, a needle's echo (grey 250) from A for END mm, then optionally a streak at
    ``streak`` grey for 6 mm past it; ``gap`` (from, to) mm: a stretch of shaft faded to
    grey 60 (out of the plane) inside it."""
    im = _speckle(seed)
    if streak is not None:
        _draw(im, A + END * D, A + (END + 6.0) * D, streak)
    _draw(im, A, A + END * D, 250)
    if gap is not None:
        _draw(im, A + gap[0] * D, A + gap[1] * D, 60)
    return _frame(im)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("streak", [None, 170])
def test_a_tip_past_the_end_of_the_echo_is_moved_back(seed, streak):
    """A tip 5 mm past the end of the echo (onto speckle, or onto a streak 80 grey levels,
    about 14 dB at 40 levels a decade, below the shaft): the end is found within a sample."""
    end = echo_end(_needle(seed, streak=streak), A, D, END + 5.0, EchoEndParams())
    assert end == pytest.approx(END, abs=2 * SPACING)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_tip_at_the_end_of_the_echo_stands(seed):
    """A tip within the drop's resolution (the window) of the echo's end is the map's own."""
    assert echo_end(_needle(seed), A, D, END + 1.0, EchoEndParams()) is None
    assert echo_end(_needle(seed), A, D, END - 1.0, EchoEndParams()) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_end_where_the_echo_goes_on(seed):
    """A saturated streak as bright as the shaft: nothing in the image tells the tip, so the
    map's tip stands; and a stretch of shaft faded to the tissue's level is no end where the
    echo comes back after it (its drop, 5 mm before a tip on a bright streak, is the largest
    in reach)."""
    assert echo_end(_needle(seed, streak=250), A, D, END + 5.0, EchoEndParams()) is None
    faded = _needle(seed, streak=210, gap=(12.0, 13.5))
    assert echo_end(faded, A, D, END + 2.0, EchoEndParams()) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_saturated_shallow_needle_ends_where_its_reverberations_end(seed):
    """A needle at 6 degrees, saturated, with three reverberation copies under it to its tip,
    and a streak on its line as bright as the shaft for 3 mm past the tip, fading over 3 mm
    more: its echo line shows no drop, its band (echo and tail) falls where the copies end."""
    a = np.array([2.0, 5.0])
    d = np.array([np.cos(np.deg2rad(6.0)), np.sin(np.deg2rad(6.0))])
    down = np.array([-d[1], d[0]])
    im = _speckle(seed)
    for off, grey in ((0.9, 255), (1.8, 230), (2.7, 200)):
        _draw(im, a + off * down, a + END * d + off * down, grey)
    for x in np.arange(0.0, 6.0, 0.1):  # the streak: 255 for 3 mm, then down to 200
        grey = 255 if x < 3.0 else 255 - 55 * (x - 3.0) / 3.0
        _draw(im, a + (END + x) * d, a + (END + x + 0.1) * d, grey)
    _draw(im, a, a + END * d, 255)
    end = echo_end(_frame(im), a, d, END + 5.0, EchoEndParams())
    assert end is not None and END - 0.2 <= end <= END + 0.8, end


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_needle_fading_as_a_whole_keeps_its_tip(seed):
    """A needle leaving the plane: its echo and its reverberation copies fade together over
    its last 6 mm to the tissue's level, and the map's tip is at its end. The band falls, but
    so does the echo line: no streak, and the band's fall moves nothing (the echo line's own
    largest drop is the other rule's, tested above)."""
    a = np.array([2.0, 5.0])
    d = np.array([np.cos(np.deg2rad(6.0)), np.sin(np.deg2rad(6.0))])
    down = np.array([-d[1], d[0]])
    im = _speckle(seed)
    for x in np.arange(0.0, END, 0.1):
        fade = min(1.0, (END - x) / 6.0)
        for off, grey in ((0.0, 250), (0.9, 250), (1.8, 230), (2.7, 200)):
            _draw(im, a + x * d + off * down, a + (x + 0.1) * d + off * down,
                  110 + fade * (grey - 110))
    assert _band_fall(_frame(im), a, d, END, EchoEndParams()) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_needle_crossing_into_darker_tissue_keeps_its_tip(seed):
    """A saturated needle with its reverberation copies passes, 8 mm along, over a layer of
    tissue two speckle spreads darker (more than layers usually differ): its band falls with
    the tissue by about 1.3 spreads, under ``band_fall_sd`` (1.5), and the map's tip at the
    needle's end stands; at a level of one spread the layer would have ended the needle."""
    from needlenet.trackers._inplane_line_echo import frame_spread

    a = np.array([2.0, 5.0])
    d = np.array([np.cos(np.deg2rad(6.0)), np.sin(np.deg2rad(6.0))])
    down = np.array([-d[1], d[0]])
    im = _speckle(seed)
    spread = frame_spread(_frame(im))
    z, x = np.mgrid[:im.shape[0], :im.shape[1]] * SPACING
    im[(x - a[0]) * d[0] + (z - a[1]) * d[1] > 8.0] -= 2.0 * spread
    for off, grey in ((0.0, 255), (0.9, 255), (1.8, 230), (2.7, 200)):
        _draw(im, a + off * down, a + END * d + off * down, grey)
    frame = _frame(np.clip(im, 0, 255))
    assert _band_fall(frame, a, d, END, EchoEndParams()) is None
    assert _band_fall(frame, a, d, END, EchoEndParams(band_fall_sd=1.0)) is not None


def test_speckle_alone_rarely_shows_an_end():
    """Along lines of speckle alone a drop of two spreads between 1.5 mm means is rare
    (seeded: 0 of 60 lines)."""
    rng = np.random.default_rng(3)
    hits = 0
    for k in range(6):
        frame = _frame(_speckle(50 + k))
        for _ in range(10):
            a = rng.uniform(2.0, 6.0, 2)
            ang = rng.uniform(0.2, 1.2)
            hits += echo_end(frame, a, np.array([np.cos(ang), np.sin(ang)]), 20.0,
                             EchoEndParams()) is not None
    assert hits == 0


def test_settings_out_of_range_are_refused():
    with pytest.raises(ValueError, match="echo end"):
        EchoEndParams(window_mm=0.0)
    with pytest.raises(ValueError, match="echo end"):
        EchoEndParams(min_drop_sd=-1.0)
    with pytest.raises(ValueError, match="echo end"):
        EchoEndParams(band_mm=(3.0, -0.5))
    with pytest.raises(ValueError, match="echo end"):
        EchoEndParams(band_fall_sd=0.0)
