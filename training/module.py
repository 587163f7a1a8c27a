"""The LightningModule: one shared step for training, validation and test, with the metrics
the issue asks for (shaft AUC, tip error in mm)."""

from __future__ import annotations

import lightning as L
import numpy as np
import torch
from torch import nn

from needlenet.eval import roc_auc

__all__ = ["LikelihoodModule", "likelihood_loss", "shaft_auc", "tip_error_mm",
           "peak_subpixel"]


def likelihood_loss(logits: torch.Tensor, target: torch.Tensor,
                    pos_weight: tuple[float, float] = (20.0, 50.0)) -> torch.Tensor:
    """Binary cross-entropy against the Gaussian targets, positives up-weighted per channel
    (the needle covers a small fraction of the image, its tip far less)."""
    w = torch.tensor(pos_weight, dtype=logits.dtype, device=logits.device)
    w = w.view(1, -1, *([1] * (logits.ndim - 2)))
    weight = 1.0 + (w - 1.0) * target
    return nn.functional.binary_cross_entropy_with_logits(logits, target, weight=weight)


def shaft_auc(prob: np.ndarray, target: np.ndarray, pos: float = 0.6, neg: float = 0.05) -> float:
    """ROC AUC of the shaft map: positives where the target exceeds ``pos`` (within ~1 needle
    radius of the centreline), negatives where it is below ``neg``; rank-based (Mann-Whitney)."""
    p = np.asarray(prob, float).ravel()
    t = np.asarray(target, float).ravel()
    return roc_auc(p[t >= pos], p[t <= neg])


def peak_subpixel(m: np.ndarray) -> np.ndarray:
    """Index of the maximum of a map, refined by the centroid of its 3^D neighbourhood."""
    idx = np.array(np.unravel_index(int(np.argmax(m)), m.shape))
    lo = np.maximum(idx - 1, 0)
    hi = np.minimum(idx + 2, m.shape)
    sub = m[tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))].astype(float)
    sub = np.maximum(sub - sub.min(), 0)
    if sub.sum() <= 0:
        return idx.astype(float)
    grids = np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi, strict=True)], indexing="ij")
    return np.array([(g * sub).sum() / sub.sum() for g in grids])


def tip_error_mm(prob_tip: np.ndarray, target_tip: np.ndarray, spacing_mm: float,
                 visible: float = 0.6) -> float:
    """Distance between the peaks of the predicted and the target tip maps (NaN when the tip
    is not visible in the frame: target peak below ``visible``)."""
    if target_tip.max() < visible:
        return float("nan")
    return float(np.linalg.norm(peak_subpixel(prob_tip) - peak_subpixel(target_tip)) * spacing_mm)


class LikelihoodModule(L.LightningModule):
    def __init__(self, net: nn.Module, modality: str, spacing_mm: float, lr: float = 3e-3,
                 max_steps: int = 1000, weight_decay: float = 1e-4,
                 target_reference: str = "centerline", normalization: str = "fixed",
                 pos_weight: tuple[float, float] = (20.0, 50.0),
                 speckle_cell_mm: float | None = None):
        super().__init__()
        self.save_hyperparameters(ignore=["net"])
        self.net = net
        self._val: list = []

    def forward(self, x):
        return self.net(x)

    def _shared_step(self, batch, stage: str):
        x, y = batch
        logits = self.net(x)
        loss = likelihood_loss(logits, y, tuple(self.hparams.get("pos_weight", (20.0, 50.0))))
        self.log(f"{stage}/loss", loss, prog_bar=stage == "train", batch_size=x.shape[0],
                 sync_dist=stage != "train")
        return loss, logits

    def training_step(self, batch, batch_idx):
        return self._shared_step(batch, "train")[0]

    def validation_step(self, batch, batch_idx):
        loss, logits = self._shared_step(batch, "val")
        prob = torch.sigmoid(logits).cpu().numpy()
        y = batch[1].cpu().numpy()
        out_spacing = self.hparams.spacing_mm * 2
        for p, t in zip(prob, y, strict=True):
            self._val.append((shaft_auc(p[0], t[0]), tip_error_mm(p[1], t[1], out_spacing)))

    def on_validation_epoch_end(self):
        if not self._val:
            return
        a = np.array(self._val, float)
        self._val = []
        auc = np.nanmean(a[:, 0]) if np.isfinite(a[:, 0]).any() else float("nan")
        tip = a[:, 1][np.isfinite(a[:, 1])]
        # under DDP every process validates on the whole held-out set: the values agree
        self.log("val/shaft_auc", float(auc), sync_dist=True)
        if tip.size:
            self.log("val/tip_error_median_mm", float(np.median(tip)), sync_dist=True)
            self.log("val/tip_within_1mm", float((tip <= 1.0).mean()), sync_dist=True)

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr,
                                weight_decay=self.hparams.weight_decay)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=self.hparams.lr,
                                                    total_steps=max(self.hparams.max_steps, 2),
                                                    pct_start=0.1)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
