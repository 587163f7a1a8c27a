"""Suite registry and the shared JSON / Markdown output of ``needlenet bench``."""

from __future__ import annotations

import json
from pathlib import Path

from ._machine import machine_description

SUITES = ("synth", "models", "inplane", "axial", "volume")


def run_suite(name: str, quick: bool = False, json_out: str | Path | None = None,
              seed: int = 0, log=print) -> dict:
    if name not in SUITES:
        raise ValueError(f"unknown suite {name!r}; available: {', '.join(SUITES)}")
    machine = machine_description()
    if name == "synth":
        from . import _synth as mod
    elif name == "models":
        from . import _models as mod
    if name in ("inplane", "axial", "volume"):
        from . import _trackers as tr

        result = getattr(tr, f"run_{name}")(quick=quick, log=log)
        md = getattr(tr, f"markdown_{name}")
    else:
        result = mod.run(quick=quick, seed=seed, log=log)
        md = mod.markdown
    result.update({"suite": name, "quick": quick, "machine": machine})
    for row in result.get("rows", []):
        row.setdefault("machine", machine["cpu"])
    result["markdown"] = md(result, machine)
    if json_out is not None:
        Path(json_out).write_text(json.dumps(result, indent=2))
    return result
