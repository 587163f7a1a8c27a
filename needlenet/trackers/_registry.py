"""Which tracker class serves which modality, and how ``--features`` picks its source."""

from __future__ import annotations

import dataclasses
import difflib
import importlib

from .._settings import convert_setting

__all__ = ["TRACKERS", "METHOD_TRACKERS", "DEFAULT_METHODS", "DEFAULT_FEATURES",
           "tracker_class", "tracker_methods", "make_tracker", "tracker_params", "FEATURE_KINDS"]

# the papers' tracker of each modality (module, class, parameter class)
TRACKERS = {
    "inplane": ("needlenet.trackers._inplane", "InplaneTracker"),
    "volume": ("needlenet.trackers._volume", "VolumeTracker"),
    "axial": ("needlenet.trackers._axial", "AxialTracker"),
}
# methods served by a tracker class of their own: (modality, method) -> (module, class)
METHOD_TRACKERS = {
    ("inplane", "line"): ("needlenet.trackers._inplane_line", "LineTracker"),
}
# what ``needlenet track FILE`` runs when no method or features are given: the whole-frame
# in-plane search (no entry side or angle assumed), and learned features
DEFAULT_METHODS = {"inplane": "line", "volume": "roi-rk", "axial": "carriere"}
DEFAULT_FEATURES = "learned"
FEATURE_KINDS = ("classical", "learned")
# each tracker class's parameter dataclass, in the tracker's module
PARAMS = {"InplaneTracker": "InplaneParams", "VolumeTracker": "VolumeTrackerParams",
          "AxialTracker": "AxialParams", "LineTracker": "LineTrackerParams"}


def tracker_methods(name: str) -> tuple[str, ...]:
    """Every method of modality ``name``: the paper's tracker's and those with a class of
    their own."""
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}")
    module, cls = TRACKERS[name]
    own = tuple(m for (n, m) in METHOD_TRACKERS if n == name)
    return own + tuple(getattr(importlib.import_module(module), cls).methods)


def tracker_class(name: str, method: str | None = None):
    """The class that runs ``method`` of modality ``name`` (the paper's tracker when
    ``method`` is None or one of its own)."""
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}")
    module, cls = METHOD_TRACKERS.get((name, method), TRACKERS[name])
    return getattr(importlib.import_module(module), cls)


def make_tracker(name: str, method: str, features: str = "classical", model: str | None = None,
                 **params):
    """A tracker of modality ``name`` with ``method`` and classical or learned features."""
    if method not in tracker_methods(name):
        raise ValueError(f"tracker {name!r} has no method {method!r}; choose one of "
                         f"{', '.join(tracker_methods(name))}")
    cls = tracker_class(name, method)
    if features not in FEATURE_KINDS:
        raise ValueError(f"features must be one of {FEATURE_KINDS}, got {features!r}")
    if features == "learned" or model is not None:
        from ..features import learned_features

        source = learned_features(name, model)
    else:
        source = cls.default_features()
    return cls(method, features=source, **params)


def tracker_params(name: str, settings, method: str | None = None):
    """The parameter dataclass of the tracker that runs ``method`` of modality ``name``
    (``InplaneParams``, ``LineTrackerParams``, ``VolumeTrackerParams``, ``AxialParams``)
    with ``settings`` applied: ``"NAME=VALUE"`` strings (or a mapping of
    names to text), a nested field as ``NAME.FIELD=VALUE``. Each value is read as the type
    of the field's default (booleans as true/false, tuples as comma-separated values); the
    dataclass then checks the result. Unknown names and unreadable values raise ValueError
    naming them."""
    tracker = tracker_class(name, method)
    cls_name = PARAMS[tracker.__name__]
    cls = getattr(importlib.import_module(tracker.__module__), cls_name)
    if isinstance(settings, dict):
        pairs = list(settings.items())
    else:
        for item in settings:
            if "=" not in item:
                raise ValueError(f"parameter {item!r}: expected NAME=VALUE")
        pairs = [(k.strip(), v) for k, v in (item.split("=", 1) for item in settings)]
    top: dict = {}
    nested: dict = {}
    fields = {f.name: f for f in dataclasses.fields(cls)}
    base = cls()
    for key, text in pairs:
        head, _, rest = key.partition(".")
        if head not in fields:
            close = difflib.get_close_matches(head, list(fields), n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise ValueError(f"unknown {cls_name} parameter {head!r}{hint} (parameters: "
                             f"{', '.join(fields)})")
        default = getattr(base, head)
        if rest:
            if not dataclasses.is_dataclass(default):
                raise ValueError(f"parameter {head} has no fields ({key!r})")
            sub = {f.name: f.type for f in dataclasses.fields(default)}
            if rest not in sub:
                raise ValueError(f"unknown {type(default).__name__} parameter {rest!r} of "
                                 f"{head} (parameters: {', '.join(sorted(sub))})")
            nested.setdefault(head, {})[rest] = convert_setting(key, text, getattr(default, rest),
                                                                sub[rest])
        else:
            top[head] = convert_setting(key, text, default, fields[head].type)
    for head, values in nested.items():
        top[head] = dataclasses.replace(top.get(head, getattr(base, head)), **values)
    return cls(**top)
