"""``train(config) -> metrics``: train a likelihood network on synth data (no CLI here).

The exact command that reproduces a shipped model is ``needlenet train MODALITY`` with the
defaults of :data:`DEFAULTS` (see README).
"""

from __future__ import annotations

import difflib
import json
import time
import warnings
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from needlenet.settings import convert_setting

from .data import DataConfig, SynthDataModule, target_reference
from .module import LikelihoodModule
from .networks import build_network, count_parameters
from .speckle import SPECKLE_MODALITIES, speckle_reference

__all__ = ["TrainConfig", "DEFAULTS", "ACCELERATORS", "config_for", "settings_for",
           "train"]


ACCELERATORS = ("cpu", "gpu", "auto")


@dataclass(frozen=True)
class TrainConfig:
    modality: str = "inplane"
    steps: int = 1500
    lr: float = 3e-3
    width: int | None = None
    pos_weight: tuple[float, float] = (20.0, 50.0)  # BCE weight of positives: shaft, tip
    out_dir: str = "runs/inplane"
    val_every: int = 250
    threads: int = 1  # the trainer's torch threads; the data worker has the other core
    # Lightning's accelerator: "cpu" (the shipped recipes), "gpu" or "auto". On a GPU machine
    # the simulation, not the network, is the bottleneck: give it the cores (num_workers).
    accelerator: str = "cpu"
    # processes per machine and machines: more than one process in all trains with Lightning's
    # DDP strategy (gloo on CPUs, NCCL on GPUs), each process simulating its own worlds
    devices: int = 1
    num_nodes: int = 1
    verbose: bool = True
    # a checkpoint written by ``train`` whose network weights this run starts from (fine-tuning);
    # its modality, spacing, normalisation and width must be this recipe's
    init: str | None = None
    data: DataConfig = field(default_factory=DataConfig)

    def __post_init__(self):
        if self.accelerator not in ACCELERATORS:
            raise ValueError(f"accelerator must be one of {', '.join(ACCELERATORS)}, got "
                             f"{self.accelerator!r}")
        for name in ("steps", "val_every", "threads", "devices", "num_nodes"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
        if not self.lr > 0:
            raise ValueError(f"lr must be positive, got {self.lr}")
        if self.width is not None and (not isinstance(self.width, int) or self.width < 1):
            raise ValueError(f"width must be a whole number of channels >= 1, got "
                             f"{self.width!r}")


# The shipped models: spacing and crop per modality (commands in README). The shipped in-plane
# model was trained on the "narrow" worlds with the "robust" normalisation (its input does not
# move with the scanner's gain or dynamic range); the "wide" worlds did worse on images synth
# did not make (needlenet bench external; docs/notes/inplane.md).
DEFAULTS = {
    "inplane": TrainConfig(modality="inplane", steps=900, out_dir="runs/inplane",
                           data=DataConfig(modality="inplane", spacing_mm=0.2, crop=96,
                                           batch_size=16, frames_per_world=24,
                                           crops_per_frame=2, shuffle_buffer=192,
                                           inplane_worlds="narrow",
                                           normalization="robust")),
    "axial": TrainConfig(modality="axial", steps=1200, out_dir="runs/axial",
                         data=DataConfig(modality="axial", spacing_mm=0.3, crop=64,
                                         batch_size=16, frames_per_world=40,
                                         crops_per_frame=2, shuffle_buffer=192,
                                         normalization="robust")),
    "volume": TrainConfig(modality="volume", steps=2000, lr=4e-3, out_dir="runs/volume",
                          data=DataConfig(modality="volume", spacing_mm=0.5, crop=40,
                                          batch_size=4, frames_per_world=8, val_frames=24,
                                          crops_per_frame=3, normalization="median")),
}


def _recipe(modality: str) -> TrainConfig:
    if modality not in DEFAULTS:
        raise ValueError(f"unknown model {modality!r}; choose one of {', '.join(DEFAULTS)}")
    return DEFAULTS[modality]


def _settable(names) -> tuple[set, set]:
    """The names a recipe change may use (fields of TrainConfig, fields of its DataConfig);
    raises ValueError on the first of ``names`` that is neither, with the closest names."""
    train_fields = set(TrainConfig.__annotations__) - {"data", "modality"}
    data_fields = set(DataConfig.__annotations__) - {"modality"}
    every = sorted(train_fields | data_fields)
    unknown = sorted(set(names) - train_fields - data_fields)
    if unknown:
        close = difflib.get_close_matches(unknown[0], every, n=3)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise ValueError(f"unknown training setting {unknown[0]!r}{hint} (settings: "
                         f"{', '.join(every)})")
    return train_fields, data_fields


def settings_for(modality: str, items) -> dict:
    """``"NAME=VALUE"`` strings (``needlenet train --param``) as changes for
    :func:`config_for`: each value read as the type of the recipe's default for that name
    (numbers, true/false, tuples as comma-separated values, text). Unknown names and
    unreadable values raise ValueError naming them."""
    cfg = _recipe(modality)
    out: dict = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"parameter {item!r}: expected NAME=VALUE")
        if name in out:
            raise ValueError(f"parameter {name} given twice")
        _, data_fields = _settable([name])
        default = getattr(cfg.data if name in data_fields else cfg, name)
        value = convert_setting(name, text, default)
        if isinstance(default, tuple) and len(value) != len(default):
            raise ValueError(f"parameter {name}: expected {len(default)} comma-separated "
                             f"values, got {text!r}")
        out[name] = value
    return out


def config_for(modality: str, **changes) -> TrainConfig:
    """The shipped recipe for ``modality`` with ``changes``: fields of :class:`TrainConfig`
    or of its :class:`DataConfig` (e.g. ``steps=500, crop=48, width=12``)."""
    cfg = _recipe(modality)
    _, data_fields = _settable(changes)
    data_changes = {k: changes.pop(k) for k in list(changes) if k in data_fields}
    if data_changes:
        cfg = replace(cfg, data=replace(cfg.data, **data_changes))
    return replace(cfg, **changes)


def _start_from(net, config: TrainConfig) -> None:
    """Load ``config.init``'s network weights into ``net``; ValueError when that checkpoint
    was trained for another modality, grid, normalisation or width."""
    from .export import load_checkpoint

    start, hp = load_checkpoint(config.init)
    for key, want in (("modality", config.modality), ("spacing_mm", config.data.spacing_mm),
                      ("normalization", config.data.normalization)):
        if hp.get(key) != want:
            raise ValueError(f"init {config.init}: a checkpoint with {key} {hp.get(key)!r}; "
                             f"this recipe trains {want!r}")
    try:
        net.load_state_dict(start.state_dict())
    except RuntimeError as exc:
        raise ValueError(f"init {config.init}: its network is not this recipe's (width "
                         f"{config.width or 'default'}): {str(exc).splitlines()[0]}") from None


def train(config: TrainConfig) -> dict:
    """Train, checkpoint and return the final validation metrics (and the loss history)."""
    import lightning as L
    from lightning.pytorch.callbacks import ModelCheckpoint

    torch.set_num_threads(config.threads)
    torch.manual_seed(config.data.seed)
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    net = build_network(config.modality, config.width)
    if config.init is not None:
        _start_from(net, config)
    speckle = speckle_reference(config.data, config.data.speckle_worlds) \
        if config.modality in SPECKLE_MODALITIES else None
    module = LikelihoodModule(net, config.modality, config.data.spacing_mm, lr=config.lr,
                              max_steps=config.steps,
                              target_reference=target_reference(config.modality),
                              normalization=config.data.normalization,
                              pos_weight=tuple(config.pos_weight), speckle_cell_mm=speckle)
    dm = SynthDataModule(config.data)
    ckpt = ModelCheckpoint(dirpath=out, filename="last", save_last=False, every_n_train_steps=
                           max(config.val_every, 1), save_top_k=1)
    history: list[float] = []
    t0 = time.time()

    class _Loss(L.Callback):
        def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
            history.append(float(outputs["loss"]) if isinstance(outputs, dict) else
                           float(outputs))

        def on_validation_end(self, trainer, pl_module):
            if trainer.sanity_checking or not config.verbose or not trainer.is_global_zero:
                return
            m = {k: round(float(v), 4) for k, v in trainer.callback_metrics.items()
                 if k.startswith("val/")}
            loss = np.mean(history[-50:]) if history else float("nan")
            print(f"step {trainer.global_step:5d}  train/loss {loss:.4f}  {m}  "
                  f"{time.time() - t0:.0f} s", flush=True)

    distributed = config.devices * config.num_nodes > 1
    trainer = L.Trainer(max_steps=config.steps, accelerator=config.accelerator,
                        devices=config.devices, num_nodes=config.num_nodes,
                        strategy="ddp" if distributed else "auto",
                        # every process validates on the whole (small) held-out set
                        use_distributed_sampler=False,
                        val_check_interval=config.val_every, check_val_every_n_epoch=None,
                        limit_val_batches=1.0, logger=False, callbacks=[ckpt, _Loss()],
                        enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0, log_every_n_steps=50)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", ".*does not have many workers.*")
        warnings.filterwarnings("ignore", ".*IterableDataset.*")
        dm.setup()
        initial = trainer.validate(module, dataloaders=dm.val_dataloader(), verbose=False)
        trainer.fit(module, datamodule=dm)
        metrics = {k: float(v) for k, v in trainer.validate(module, datamodule=dm,
                                                            verbose=False)[0].items()}
    final = out / "model.ckpt"
    trainer.save_checkpoint(final)  # written by global rank 0 only
    metrics.update({"val_loss_initial": float(initial[0]["val/loss"]),
                    "train_seconds": time.time() - t0, "steps": config.steps,
                    "processes": config.devices * config.num_nodes,
                    "parameters": count_parameters(net), "checkpoint": str(final),
                    "loss_first": float(np.mean(history[:20])) if history else float("nan"),
                    "loss_last": float(np.mean(history[-20:])) if history else float("nan")})
    if trainer.is_global_zero:
        (out / "config.json").write_text(json.dumps(asdict(config), indent=1))
        (out / "metrics.json").write_text(json.dumps(metrics, indent=1))
    metrics["global_rank"] = trainer.global_rank
    return metrics
