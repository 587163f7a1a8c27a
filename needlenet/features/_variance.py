"""Carriere 2016's classical feature: the variance image of eq. (1), normalised to [0, 1]."""

from __future__ import annotations

import numpy as np

from ..backends import variance_image
from ._base import FeatureSource, Frame, Likelihood

__all__ = ["VarianceFeatures"]


class VarianceFeatures(FeatureSource):
    """Carriere 2016, section II, eq. (1): V = (I - mean(I))^2 divided by its maximum.

    The mean is the mean of the whole frame (the paper's I-bar), so the map is computed on
    the whole frame even when ``roi`` is given: cutting the frame first would change the
    mean and the normalisation. A constant frame gives zeros (the back end's convention).
    The map has no tip channel (``tip=None``): an axial slice shows a cross-section of the
    shaft, not the tip.
    """

    name = "variance"

    def likelihood(self, frame: Frame, roi: tuple[slice, ...] | None = None) -> Likelihood:
        v = variance_image(np.asarray(frame.image))  # Carriere 2016, eq. (1), / max
        return Likelihood(shaft=v.astype(np.float32), tip=None, source=self.name)
