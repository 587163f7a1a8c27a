"""``needlenet train`` and ``needlenet export``: the training extra's two commands."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, check_output, seed

_TRAIN_EXTRA = ("needs the training extra (torch, lightning, onnx): "
                "pip install torch==2.13.0 && pip install 'needlenet[train]'")


def _require_training(cmd: str) -> None:
    import importlib.util

    def absent(name: str) -> bool:
        try:
            return importlib.util.find_spec(name) is None
        except (ImportError, ValueError):
            return True

    missing = [m for m in ("torch", "lightning", "onnx") if absent(m)]
    if missing:
        raise CLIError(f"{cmd} {_TRAIN_EXTRA} (missing: {', '.join(missing)})")


# -- train --------------------------------------------------------------------------------

def add_train_parser(sub) -> None:
    p = sub.add_parser("train", help="train a needle likelihood network on synth data",
                       description="Train a likelihood network (shaft and tip maps) on "
                                   "sequences simulated on the fly. " + _TRAIN_EXTRA)
    p.add_argument("model", help="inplane, axial or volume")
    p.add_argument("--steps", type=int, help="optimisation steps (default: the shipped recipe)")
    p.add_argument("--out", help="output directory (default runs/MODEL)")
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument("--workers", type=int, default=2,
                   help="data-generating processes (default 2: the trainer itself needs little)")
    p.add_argument("--accelerator", default="cpu", choices=("cpu", "gpu", "auto"),
                   help="where the network trains (default cpu, as the shipped models did; "
                        "on a GPU machine the simulation is the bottleneck: raise --workers)")
    p.add_argument("--devices", type=int, default=1,
                   help="training processes on this machine (default 1); more than one process "
                        "in all trains with Lightning's DDP strategy (gloo on CPUs, NCCL on "
                        "GPUs), each with its own simulated worlds")
    p.add_argument("--num-nodes", type=int, default=1,
                   help="machines (default 1); launch one copy of this command per machine "
                        "as Lightning expects (SLURM's srun, or torchrun's environment)")
    p.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="change one setting of the recipe: a field of training.train."
                        "TrainConfig or of its DataConfig, e.g. --param width=16 --param "
                        "crop=48 --param cr_range=1.5,3.0; repeatable")
    p.add_argument("--init", metavar="CKPT",
                   help="start from the network of a checkpoint written by 'needlenet train' "
                        "(fine-tuning; the same model and width), e.g. the shipped in-plane "
                        "model's base, training/checkpoints/inplane_base.ckpt")
    p.add_argument("--export", help="also export the result to this .onnx file")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run_train)


def run_train(args) -> int:
    if args.model not in ("inplane", "axial", "volume"):
        raise CLIError(f"train: unknown model {args.model!r}; choose inplane, axial or volume")
    for flag, value in (("--steps", args.steps), ("--devices", args.devices),
                        ("--num-nodes", args.num_nodes)):
        if value is not None and value < 1:
            raise CLIError(f"train: {flag} must be at least 1, got {value}")
    export = check_output(args.export, ".onnx", args.overwrite, "--export")
    if args.init is not None and not Path(args.init).is_file():
        raise CLIError(f"train: --init {args.init}: no such checkpoint file")
    _require_training("train")
    from training.train import train

    cfg = _config(args)
    if cfg.accelerator == "gpu":
        import torch

        if not torch.cuda.is_available():
            raise CLIError(f"train: --accelerator gpu, but torch {torch.__version__} sees no "
                           "GPU")
    out = Path(cfg.out_dir)
    if (out / "model.ckpt").exists() and not args.overwrite:
        raise CLIError(f"train: {out / 'model.ckpt'} exists; pass --overwrite or --out DIR")
    try:
        metrics = train(cfg)
    except ValueError as exc:
        if cfg.init is None or not str(exc).startswith(("init ", "checkpoint ")):
            raise
        raise CLIError(f"train: --init: {exc}") from None
    if metrics.pop("global_rank", 0) != 0:
        return 0  # a DDP worker process: rank 0 reports and exports
    for k, v in metrics.items():
        print(f"{k}: {v}")
    if export is not None:
        from training.export import export_onnx, load_checkpoint

        net, hp = load_checkpoint(metrics["checkpoint"])
        r = export_onnx(net, hp["modality"], hp["spacing_mm"], export, overwrite=args.overwrite,
                        extra_metadata={"train_steps": cfg.steps, "train_seed": args.seed,
                                        **({"train_params": " ".join(args.param)}
                                           if args.param else {}),
                                        **({"train_init": _describe(args.init)}
                                           if args.init else {})},
                        target_reference=hp.get("target_reference", "centerline"),
                        normalization=hp.get("normalization", "fixed"),
                        speckle_cell_mm=hp.get("speckle_cell_mm"))
        print(f"wrote {export} ({r['bytes']} bytes, onnxruntime vs torch {r['max_abs_diff']:.1e})")
    return 0


def _describe(path: str) -> str:
    """A checkpoint as the model's metadata names it: file name and SHA-256 (first 16)."""
    import hashlib

    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
    return f"{Path(path).name} sha256:{digest}"


def _config(args):
    """The shipped recipe of ``args.model`` with the options and ``--param`` settings."""
    from training.train import config_for, settings_for

    changes = {"seed": args.seed, "num_workers": args.workers,
               "accelerator": args.accelerator, "devices": args.devices,
               "num_nodes": args.num_nodes}
    if args.steps is not None:
        changes["steps"] = args.steps
    if args.out:
        changes["out_dir"] = args.out
    if args.init:
        changes["init"] = str(args.init)
    try:
        settings = settings_for(args.model, args.param)
        own = sorted(set(settings) & {"seed", "num_workers", "accelerator", "steps", "out_dir",
                                      "devices", "num_nodes", "init"})
        if own:
            raise ValueError(f"set {', '.join(own)} with its own option (--seed, --workers, "
                             "--accelerator, --steps, --out, --devices, --num-nodes, --init), "
                             "not --param")
        return config_for(args.model, **changes, **settings)
    except ValueError as exc:
        raise CLIError(f"train: --param: {exc}") from None


# -- export -------------------------------------------------------------------------------

def add_export_parser(sub) -> None:
    p = sub.add_parser("export", help="export a training checkpoint to ONNX",
                       description="Export a checkpoint to ONNX (input 'image', output "
                                   "'likelihood', dynamic spatial axes), verified against torch.")
    p.add_argument("checkpoint")
    p.add_argument("--out", required=True, help="the .onnx file")
    p.add_argument("--overwrite", action="store_true")
    p.set_defaults(func=run_export)


def run_export(args) -> int:
    out = check_output(args.out, ".onnx", args.overwrite, "--out")
    _require_training("export")
    from training.export import ExportError, export_onnx, load_checkpoint

    try:
        net, hp = load_checkpoint(args.checkpoint)
        r = export_onnx(net, hp["modality"], hp["spacing_mm"], out, overwrite=args.overwrite,
                        target_reference=hp.get("target_reference", "centerline"),
                        normalization=hp.get("normalization", "fixed"),
                        speckle_cell_mm=hp.get("speckle_cell_mm"))
    except (ValueError, ExportError) as exc:
        raise CLIError(f"export: {exc}") from None
    print(f"wrote {out} ({r['bytes']} bytes, opset {r['opset']}, IR {r['ir_version']}, "
          f"onnxruntime vs torch {r['max_abs_diff']:.1e})")
    return 0
