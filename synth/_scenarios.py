"""Seeded scenarios reproducing the protocols of the five papers.

Each scenario is a frozen dataclass of parameters with the paper's defaults, a ``draw``
method that makes every random choice of the scenario in one place from one seed (so a seed
reproduces a sequence exactly), and a ``build`` method that turns the draw into a scanner and
a trajectory. :func:`generate` runs it and returns a labelled :class:`Sequence`.

| name            | paper           | modality | what moves                                      |
|-----------------|-----------------|----------|-------------------------------------------------|
| ``inplane``       | Mathiassen 2017 | inplane  | needle inserted in the plane of a static probe  |
| ``volume``        | Zhao 2013       | volume   | needle inserted in a static sector volume       |
| ``volume-motion`` | Chatelain 2013  | volume   | insertion, withdrawal, re-insertion; phantom    |
| ``axial``         | Carriere 2016   | axial    | curved needle; probe stepped 0.5 mm per frame   |
| ``servo``         | Ye 2025         | axial    | Ye's tip path; probe plane following the tip    |
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import fields

import numpy as np

from ._render import render_sequence
from ._scenario_axial import AxialScenario, ServoScenario, ye_insertion_velocity
from ._scenario_base import BACKGROUNDS, MAX_FRAME_PIXELS, random_scattering_map
from ._scenario_inplane import InplaneScenario
from ._scenario_volume import VolumeMotionScenario, VolumeScenario
from ._sequence import Sequence

__all__ = ["SCENARIOS", "generate", "scenario_params", "random_scattering_map", "describe",
           "BACKGROUNDS", "MAX_FRAME_PIXELS", "ye_insertion_velocity"]


SCENARIOS = {
    "inplane": InplaneScenario,
    "volume": VolumeScenario,
    "volume-motion": VolumeMotionScenario,
    "axial": AxialScenario,
    "servo": ServoScenario,
}


def scenario_params(name: str, **overrides):
    """The scenario's parameter dataclass with ``overrides`` applied and validated."""
    if name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; choose one of {sorted(SCENARIOS)}")
    cls = SCENARIOS[name]
    names = {f.name for f in fields(cls)}
    bad = [k for k in overrides if k not in names]
    if bad:
        raise ValueError(f"scenario {name!r} has no parameter {bad[0]!r}; "
                         f"it has {sorted(names)}")
    p = cls(**overrides)
    p.validate()
    return p


def generate(name: str, seed: int = 0, progress: bool = False, timings: dict | None = None,
             **overrides) -> Sequence:
    """Generate a labelled sequence of scenario ``name``; the same seed gives the same data.

    ``timings`` (optional) receives the world set-up time and per-frame times.
    """
    p = scenario_params(name, **overrides)
    rng = np.random.default_rng(seed)
    draw = p.draw(rng)  # every random choice of the scenario, in one place
    scanner, traj = p.build(draw)
    noise_rng = np.random.default_rng([seed, 1])
    meta = {
        "scenario": name, "paper": p.paper, "seed": int(seed),
        "params": _jsonable(dataclasses.asdict(p)), "draw": _jsonable(draw),
        "imaging": _jsonable(dataclasses.asdict(scanner.params)),
        "probe": {"type": type(scanner.probe).__name__,
                  **_jsonable(dataclasses.asdict(scanner.probe))},
        "needle": {**_jsonable(dataclasses.asdict(scanner.world.needle)),
                   "radius_mm": scanner.world.needle.radius_mm},
        "tissue_density_per_mm3": scanner.world.tissue.density_per_mm3,
        "zhao_mode": bool(scanner.zhao_mode),
    }
    t0 = time.perf_counter()
    seq = render_sequence(scanner, traj, p.modality, noise_rng, meta, target_cr=p.cr,
                          progress=progress, timings=timings)
    if timings is not None:
        timings["total_s"] = time.perf_counter() - t0
    return seq


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not np.isfinite(x):
        return str(x)
    return x


def describe() -> str:
    """A human-readable list of the scenarios with their parameters and defaults."""
    lines = []
    for name, cls in SCENARIOS.items():
        doc = " ".join((cls.__doc__ or "").split())
        lines.append(f"{name}  [{cls.modality}]  {doc}")
        for f in fields(cls):
            if f.default is not dataclasses.MISSING:
                default = f.default
            elif f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            else:
                default = "(required)"
            if isinstance(default, dict):
                lines.append(f"    {f.name}={default} (Python API: a dict of overrides)")
            else:
                lines.append(f"    --param {f.name}={default}")
        lines.append("")
    return "\n".join(lines)
