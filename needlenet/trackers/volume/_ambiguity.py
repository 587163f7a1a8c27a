"""What one volume leaves unknown about the needle it shows, as a tip covariance (mm^2) added
to the filter's: the in-plane `line` tracker's two terms (:mod:`.._inplane_line_tip`) in 3D.

Along the axis, the places the measurement offered for the tip (the likelihood's drop, the
image's change point, the tip map's choice) spread over D mm: the tip anywhere between them,
D^2 / 12 along the axis. Across it, the second moment of the map's samples at the threshold
within ``BAND_READ_MM`` of the axis, between the entry and the tip, beyond that of a needle's
own image (a disc of ``inlier_radius_mm``, Zhao's eq. (B5) r, "the expected radius of the
needle in the image": r^2 / 4 per direction): zero for a needle's band, the elevation blur of
a deep phased-array volume or an interface merged with the needle where the band is wider.
"""

from __future__ import annotations

import numpy as np

from .._base import tip_spread_covariance
from ._geometry import Volume, perpendiculars

__all__ = ["BAND_READ_MM", "measurement_ambiguity"]

BAND_READ_MM = 2.0  # the band read around the axis: the in-plane search's explained_mm
_SAMPLES = 256  # the most samples along the axis (and a quarter of it across each way)


def measurement_ambiguity(vol: Volume, model, a_entry: float, a_tip: float, level: float,
                          places: list[float], needle_radius_mm: float) -> np.ndarray:
    """The covariance (3 x 3, mm^2, point order) of the module's doc for a needle found on
    ``model`` from ``a_entry`` to ``a_tip`` (its parameter, mm) at map ``level``; ``places``:
    the tip's candidate parameters."""
    u = np.asarray(model.principal_direction, float)
    u = u / np.linalg.norm(u)
    along = tip_spread_covariance(u, max(places) - min(places) if places else 0.0)
    # read at the voxel size, at most _SAMPLES along the axis and across it (fine voxels)
    step = float(np.min(vol.spacing))
    length = a_tip - a_entry
    if not length >= 0.0:
        return along
    a = a_entry + np.linspace(0.0, length, min(int(length / step) + 1, _SAMPLES))
    off = np.linspace(-BAND_READ_MM, BAND_READ_MM,
                      min(2 * int(BAND_READ_MM / step) + 1, _SAMPLES // 4 + 1))
    s1, s2 = (g.ravel() for g in np.meshgrid(off, off, indexing="ij"))
    disc = s1 ** 2 + s2 ** 2 <= BAND_READ_MM ** 2
    s1, s2 = s1[disc], s2[disc]
    e1, e2 = perpendiculars(u)
    pts = model.points_at(a)[None, :, :] + (s1[:, None, None] * e1 + s2[:, None, None] * e2)
    counts = (vol.sample(vol.values, pts) >= level).sum(axis=1)  # per offset
    if not counts.any():
        return along
    w = counts / counts.sum()
    m = np.array([[w @ (s1 * s1), w @ (s1 * s2)], [w @ (s1 * s2), w @ (s2 * s2)]])
    var, vec = np.linalg.eigh(m)
    extra = (vec * np.maximum(var - needle_radius_mm ** 2 / 4.0, 0.0)) @ vec.T
    basis = np.stack([e1, e2], axis=1)  # (3, 2)
    return along + basis @ extra @ basis.T
