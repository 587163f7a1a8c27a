"""Speckle statistics: the checks that the simulated speckle is real.

In fully developed speckle the envelope is Rayleigh distributed: its mean over its standard
deviation is sqrt(pi / (4 - pi)) = 1.91, and its log (20 log10) has a standard deviation of
5.57 dB. The speckle size, the full width at half maximum of the normalised autocovariance of
the intensity, equals the FWHM of a Gaussian PSF's amplitude.

Two effects move a measurement of the log-compressed image away from 5.57 dB, both physical or
part of the display, not flaws of the speckle:

- clipping to black: over 70 dB with unit speckle at grey 70, the darkest 0.7% of the speckle
  falls below grey 0 and is clipped, which lowers the expected standard deviation to 5.45 dB
  (the idealised check of ``needlenet bench synth`` reads 5.41; scenario frames 5.47-5.52 in 2 mm
  depth bands away from the needle and its shadow, seeds 4 and 0; 5.57 +- 0.3 is tested);
- the needle's acoustic shadow and reverberation tail: bands that include the tissue under the
  needle read 5.7-6.7 dB on Mathiassen's frames (seeds 0 and 1 at 10 mm/s, pixels 1-4 mm from
  the shaft; 6.7 mid-insertion), and 5.40-5.51 dB on the same frames without that tissue: a
  shadow (35% of the amplitude, -9 dB) and the comet tail add their own grey-level spread to
  the speckle's.

Compounding (``ImagingParams.compound_looks``) averages independent looks in intensity and so
lowers the spread, to :func:`speckle_log_std_db` of the number of looks.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RAYLEIGH_SNR", "RAYLEIGH_LOG_STD_DB", "envelope_snr", "log_std_db",
           "speckle_fwhm", "speckle_log_std_db"]

RAYLEIGH_SNR = float(np.sqrt(np.pi / (4.0 - np.pi)))  # 1.913
RAYLEIGH_LOG_STD_DB = float(10.0 / np.log(10.0) * np.pi / np.sqrt(6.0))  # 5.57 dB


def speckle_log_std_db(looks: int = 1) -> float:
    """Standard deviation (dB) of the log-compressed speckle of ``looks`` independent looks
    averaged in intensity (a Gamma(looks) intensity): 10 / ln 10 sqrt(psi'(looks)); 5.57 dB
    for one look, 3.49 for two, 2.73 for three. Compounding lowers it; correlated looks (as
    from close steering angles) lower it less."""
    from scipy.special import polygamma

    return float(10.0 / np.log(10.0) * np.sqrt(polygamma(1, int(looks))))


def envelope_snr(envelope: np.ndarray) -> float:
    """Mean over standard deviation of an envelope region (1.91 for Rayleigh)."""
    e = np.asarray(envelope, float).ravel()
    if e.size < 2 or e.std() == 0:
        raise ValueError("envelope_snr: need a non-constant region")
    return float(e.mean() / e.std())


def log_std_db(image: np.ndarray, dynamic_range_db: float) -> float:
    """Standard deviation, in dB, of a log-compressed 8-bit region over ``dynamic_range_db``."""
    return float(np.asarray(image, float).std() * dynamic_range_db / 255.0)


def speckle_fwhm(envelope: np.ndarray, spacing_mm) -> tuple[float, ...]:
    """FWHM (mm) of the normalised intensity autocovariance along each array axis."""
    e = np.asarray(envelope, float)
    intensity = e**2 - (e**2).mean()
    pad = [(0, n) for n in intensity.shape]
    f = np.fft.rfftn(np.pad(intensity, pad))
    ac = np.fft.irfftn(np.abs(f) ** 2, s=[2 * n for n in intensity.shape],
                       axes=list(range(intensity.ndim)))
    ac /= ac.flat[0]
    out = []
    for axis, sp in enumerate(np.atleast_1d(spacing_mm)):
        prof = np.moveaxis(ac, axis, 0)[(slice(None),) + (0,) * (ac.ndim - 1)]
        below = np.flatnonzero(prof < 0.5)
        if len(below) == 0:
            out.append(float("nan"))
            continue
        k = below[0]
        # linear interpolation of the half-maximum crossing between lags k-1 and k
        lag = (k - 1) + (prof[k - 1] - 0.5) / (prof[k - 1] - prof[k])
        out.append(float(2.0 * lag * sp))
    return tuple(out)
