"""Score learned-model candidates by the model-choice rules of docs/notes/inplane.md and
docs/notes/volume-model.md, against the shipped model.

    python tools/choose_model.py inplane [CANDIDATE.onnx ...] [--work DIR]
    python tools/choose_model.py volume [CANDIDATE.onnx ...]

Per set, with learned features and the default tracker: (needle frames tracked within 3 mm,
less needle frames tracked more than 3 mm off) over needle frames, less the share of
needle-free frames reported ``tracking``: a confident wrong answer costs what a good one earns.

- ``inplane``: the validation set (``needlenet/data/validation``), six copies of it through a
  scanner's post-processing (``tools/postprocessed_set.py``: bilateral, median, non-local means,
  unsharp masking, JPEG, Perona-Malik diffusion, each at its default strength) and four as
  another recording would show it (``tools/recording_conditions.py``: receiver noise of 5 grey
  levels, a gain falling by 40 grey levels over the depth, a brighter display that clips the
  needle to white (grey levels x 1.25: real recordings are often brighter than the set), pixels
  twice as large), written once under ``--work`` (default ``runs/choice_sets``). A candidate
  passes when no set has more than 2% of its needle-free frames ``tracking`` and its mean score
  over the eleven beats the shipped model's.
- ``volume``: the volume validation set (``needlenet/data/validation_volume``). A candidate
  passes when no needle-free volume is ``tracking`` and its score beats the shipped model's.

A pass is the first step of the rule; the synth suites and the tests follow (the notes). The
test sets (``needlenet/data/external*``) are never scored here.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

import recording_conditions  # noqa: E402
from postprocessed_set import DEFAULTS, write_copies  # noqa: E402

from needlenet.bench import _external  # noqa: E402

COPIES = ("bilateral", "median", "nlm", "sharpen", "jpeg", "diffusion")
# (name, recording_conditions operation, value)
CONDITIONS = (("noise5", "noise", 5.0), ("ramp_down", "ramp", -40.0), ("bright", "gain", 1.25),
              ("pixels2", "scale", 2.0))
MAX_FALSE = 0.02  # in-plane: the needle-free target, on every set


def postprocessed_copies(src: Path, work: Path) -> list[Path]:
    """The copies of ``src`` through each of :data:`COPIES`, written under ``work`` once."""
    files = sorted(src.glob("*.npz"))
    out = []
    for op in COPIES:
        dst = work / op
        if not all((dst / f.name).exists() for f in files):
            dst.mkdir(parents=True, exist_ok=True)
            write_copies(files, dst, op, DEFAULTS[op])
        out.append(dst)
    return out


def condition_copies(src: Path, work: Path) -> list[Path]:
    """The copies of ``src`` under each of :data:`CONDITIONS`, written under ``work`` once
    (by ``tools/recording_conditions.py``)."""
    files = sorted(src.glob("*.npz"))
    out = []
    for name, op, value in CONDITIONS:
        dst = work / name
        if not all((dst / f.name).exists() for f in files):
            recording_conditions.write_copies(files, dst, op, value, overwrite=True)
        out.append(dst)
    return out


def score_set(directory: Path, model: str | None) -> tuple[float, float]:
    """(the rule's score, the needle-free `tracking` share) of one set, learned features."""
    result = _external.run(directory=directory, model=model, features=("learned",),
                           log=lambda *a: None)
    pooled = next(r for r in result["rows"] if r["sequence"] == "pooled")
    # the bench's score: the share within 3 mm less the needle-free share
    wrong = pooled.get("wrong_fraction") or 0.0
    return pooled["score"] - wrong, pooled.get("false_tracking_fraction") or 0.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("modality", choices=("inplane", "volume"))
    ap.add_argument("candidates", nargs="*", help="ONNX models to score beside the shipped one")
    ap.add_argument("--work", default=str(ROOT / "runs" / "choice_sets"),
                    help="where the in-plane post-processed copies are written (once)")
    a = ap.parse_args(argv)
    for c in a.candidates:
        if not Path(c).is_file():
            ap.error(f"{c}: no such model file")
    data = ROOT / "needlenet" / "data"
    if a.modality == "inplane":
        sets = [data / "validation"] + postprocessed_copies(data / "validation", Path(a.work)) \
            + condition_copies(data / "validation", Path(a.work))
    else:
        sets = [data / "validation_volume"]
    names = [s.name for s in sets]
    print(f"{'model':28s} {'mean':>6s}  " + "  ".join(f"{n[:9]:>14s}" for n in names))
    shipped = None
    for model in [None, *a.candidates]:
        scores = [score_set(s, model) for s in sets]
        mean = float(np.mean([s for s, _ in scores]))
        worst_false = max(f for _, f in scores)
        limit = MAX_FALSE if a.modality == "inplane" else 0.0
        if model is None:
            shipped, verdict = mean, "shipped"
        else:
            verdict = "passes" if worst_false <= limit and mean > shipped else "fails"
        cells = "  ".join(f"{s:6.3f} fa {f:4.0%}" for s, f in scores)
        label = "shipped" if model is None else Path(model).name
        print(f"{label[:28]:28s} {mean:6.3f}  {cells}  {verdict}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
