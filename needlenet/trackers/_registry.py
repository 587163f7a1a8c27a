"""Which tracker class serves which modality, and how ``--features`` picks its source."""

from __future__ import annotations

import importlib

__all__ = ["TRACKERS", "tracker_class", "make_tracker", "FEATURE_KINDS"]

TRACKERS = {
    "inplane": ("needlenet.trackers._inplane", "InplaneTracker"),
    "volume": ("needlenet.trackers._volume", "VolumeTracker"),
    "axial": ("needlenet.trackers._axial", "AxialTracker"),
}
FEATURE_KINDS = ("classical", "learned")


def tracker_class(name: str):
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}")
    module, cls = TRACKERS[name]
    return getattr(importlib.import_module(module), cls)


def make_tracker(name: str, method: str, features: str = "classical", model: str | None = None,
                 **params):
    """A tracker of modality ``name`` with ``method`` and classical or learned features."""
    cls = tracker_class(name)
    if method not in cls.methods:
        raise ValueError(f"tracker {name!r} has no method {method!r}; choose one of "
                         f"{', '.join(cls.methods)}")
    if features not in FEATURE_KINDS:
        raise ValueError(f"features must be one of {FEATURE_KINDS}, got {features!r}")
    if features == "learned" or model is not None:
        from ..features import learned_features

        source = learned_features(name, model)
    else:
        source = cls.default_features()
    return cls(method, features=source, **params)
