"""Which tracker class serves which modality, and how ``--features`` picks its source."""

from __future__ import annotations

import dataclasses
import difflib
import importlib

from ..settings import convert_setting

__all__ = ["TRACKERS", "METHOD_TRACKERS", "DEFAULT_METHODS", "DEFAULT_FEATURES",
           "tracker_class", "tracker_methods", "make_tracker", "tracker_params", "FEATURE_KINDS"]

# the papers' tracker of each modality (module, class, parameter class)
TRACKERS = {
    "inplane": ("needlenet.trackers._inplane", "InplaneTracker"),
    "volume": ("needlenet.trackers.volume", "VolumeTracker"),
    "axial": ("needlenet.trackers._axial", "AxialTracker"),
}
# methods served by a tracker class of their own: (modality, method) -> (module, class)
METHOD_TRACKERS = {
    ("inplane", "line"): ("needlenet.trackers._inplane_line", "LineTracker"),
}
# what ``needlenet track FILE`` runs when no method or features are given: the whole-frame
# in-plane search (no entry side or angle assumed), Zhao's ROI-RK, Carriere's tracker
DEFAULT_METHODS = {"inplane": "line", "volume": "roi-rk", "axial": "carriere"}
# the features each modality's default runs: those that track best on the PyMUST validation
# sets (images needlenet did not make; docs/results.md, External): learned in-plane and axial,
# classical for volumes (ROI-RK's classical start tests refuse tissue the learned 3D map rates
# as needle)
DEFAULT_FEATURES = {"inplane": "learned", "volume": "classical", "axial": "learned"}
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


def make_tracker(name: str, method: str | None = None, features: str | None = None,
                 model: str | None = None, **params):
    """A tracker of modality ``name`` (``inplane``, ``volume``, ``axial``) with ``method``
    and ``features`` (``classical`` or ``learned``; ``model``: an ONNX file for the learned
    map); either left out, the one ``needlenet track`` runs (:data:`DEFAULT_METHODS`,
    :data:`DEFAULT_FEATURES`; learned when a model is given). ``params``: the tracker's own
    keyword arguments (``params=``, ``seed=`` or ``rng=``)."""
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose one of {', '.join(TRACKERS)}")
    method = DEFAULT_METHODS[name] if method is None else method
    if features is None:
        features = "learned" if model is not None else DEFAULT_FEATURES[name]
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
    names to text), a nested field as ``NAME.FIELD=VALUE``. A class that composes groups of
    fields (``VolumeTrackerParams.groups``) also takes each group's fields by their own names.
    Each value is read as the type of the field's default (booleans as true/false, tuples as
    comma-separated values); the dataclass then checks the result. Unknown names and
    unreadable values raise ValueError naming them."""
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
    base = cls()
    paths = _setting_paths(cls, base)
    changes: dict = {}  # nested: field name -> value, or -> the changes of a nested dataclass
    for key, text in pairs:
        head, *rest = key.split(".")
        if head not in paths:
            close = difflib.get_close_matches(head, list(paths), n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise ValueError(f"unknown {cls_name} parameter {head!r}{hint} (parameters: "
                             f"{', '.join(paths)})")
        path = paths[head] + tuple(rest)
        owner, default = base, base
        for depth, part in enumerate(path):
            if depth >= len(paths[head]):  # a part the user named after the field
                done = ".".join([head, *rest[:depth - len(paths[head])]])
                if not dataclasses.is_dataclass(default):
                    raise ValueError(f"parameter {done} has no fields ({key!r})")
                sub = {f.name for f in dataclasses.fields(default)}
                if part not in sub:
                    raise ValueError(f"unknown {type(default).__name__} parameter {part!r} of "
                                     f"{done} (parameters: {', '.join(sorted(sub))})")
            owner, default = default, getattr(default, part)
        field = {f.name: f for f in dataclasses.fields(owner)}[path[-1]]
        node = changes
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = convert_setting(key, text, default, field.type)
    return cls(**{k: _replaced(getattr(base, k), v) for k, v in changes.items()})


def _setting_paths(cls, base) -> dict[str, tuple[str, ...]]:
    """Every name ``tracker_params`` takes at the top level of parameter class ``cls``, with
    the path of fields it sets: the class's own fields, then the fields of each group it
    composes (``cls.groups``) under their own names."""
    paths = {f.name: (f.name,) for f in dataclasses.fields(cls)}
    for group in getattr(cls, "groups", ()):
        for f in dataclasses.fields(getattr(base, group)):
            paths.setdefault(f.name, (group, f.name))
    return paths


def _replaced(value, changes):
    """``value`` with ``changes`` applied: a nested dataclass's changed fields, at any depth."""
    if not isinstance(changes, dict):
        return changes
    return dataclasses.replace(value, **{k: _replaced(getattr(value, k), v)
                                         for k, v in changes.items()})
