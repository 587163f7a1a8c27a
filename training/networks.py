"""Small CNNs that predict needle likelihood maps, designed for CPU inference.

A strided stem, depthwise-separable blocks (a depthwise 3x3(x3) convolution then a pointwise
1x1(x1) one) with growing dilation for context, one skip connection at half resolution, and a
1x1 head with two output channels: shaft and tip logits. The output is at half the input's
resolution (``OUTPUT_STRIDE``); the runtime maps it back to the frame's grid. Inputs must have
sides divisible by ``INPUT_MULTIPLE`` (the runtime pads).

Refinement stages, oriented sums and a local-contrast input channel were tried for the volume
model and did not beat this network; their figures are in docs/notes/volume-model.md.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["NeedleNet2D", "NeedleNet3D", "build_network", "OUTPUT_STRIDE", "INPUT_MULTIPLE"]

OUTPUT_STRIDE = 2
INPUT_MULTIPLE = 4


class _DSBlock(nn.Module):
    """Depthwise-separable residual block: depthwise conv (dilated) -> BN -> ReLU -> pointwise
    conv -> BN, plus the input (a 1x1 projection when channels or stride change)."""

    def __init__(self, conv, bn, c_in: int, c_out: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        k = 3
        pad = dilation
        self.dw = conv(c_in, c_in, k, stride=stride, padding=pad, dilation=dilation,
                       groups=c_in, bias=False)
        self.bn1 = bn(c_in)
        self.pw = conv(c_in, c_out, 1, bias=False)
        self.bn2 = bn(c_out)
        self.act = nn.ReLU(inplace=True)
        self.skip = None
        if stride != 1 or c_in != c_out:
            self.skip = nn.Sequential(conv(c_in, c_out, 1, stride=stride, bias=False), bn(c_out))

    def forward(self, x):
        y = self.act(self.bn1(self.dw(x)))
        y = self.bn2(self.pw(y))
        return self.act(y + (x if self.skip is None else self.skip(x)))


class _NeedleNet(nn.Module):
    def __init__(self, dims: int, width: int = 16, in_channels: int = 1, out_channels: int = 2,
                 dilations: tuple[int, ...] = (1, 2, 4, 8)):
        super().__init__()
        conv = nn.Conv2d if dims == 2 else nn.Conv3d
        bn = nn.BatchNorm2d if dims == 2 else nn.BatchNorm3d
        self.dims = dims
        self.stem = nn.Sequential(conv(in_channels, width, 3, stride=2, padding=1, bias=False),
                                  bn(width), nn.ReLU(inplace=True))  # 1/2
        self.block_half = _DSBlock(conv, bn, width, width)
        self.down = _DSBlock(conv, bn, width, 2 * width, stride=2)  # 1/4
        self.context = nn.Sequential(*[_DSBlock(conv, bn, 2 * width, 2 * width, dilation=d)
                                       for d in dilations])
        self.up_proj = nn.Sequential(conv(2 * width, width, 1, bias=False), bn(width))
        self.fuse = _DSBlock(conv, bn, width, width)
        self.head = conv(width, out_channels, 1)
        self.mode = "bilinear" if dims == 2 else "trilinear"

    def forward(self, x):
        h = self.block_half(self.stem(x))
        c = self.context(self.down(h))
        u = nn.functional.interpolate(self.up_proj(c), size=h.shape[2:], mode=self.mode,
                                      align_corners=False)
        return self.head(self.fuse(h + u))  # logits at 1/2 resolution


class NeedleNet2D(_NeedleNet):
    """For ``inplane`` and ``axial`` images: (N, 1, H, W) -> (N, 2, H/2, W/2) logits."""

    def __init__(self, width: int = 16, **kw):
        super().__init__(2, width=width, **kw)


class NeedleNet3D(_NeedleNet):
    """For volumes: (N, 1, D, H, W) -> (N, 2, D/2, H/2, W/2) logits."""

    def __init__(self, width: int = 8, **kw):
        super().__init__(3, width=width, dilations=kw.pop("dilations", (1, 2, 4)), **kw)


def build_network(modality: str, width: int | None = None) -> nn.Module:
    if modality in ("inplane", "axial"):
        return NeedleNet2D(width=width or 16)
    if modality == "volume":
        return NeedleNet3D(width=width or 8)
    raise ValueError(f"unknown modality {modality!r}")


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _check() -> None:  # pragma: no cover - a quick manual check
    for m, shape in ((NeedleNet2D(), (1, 1, 64, 96)), (NeedleNet3D(), (1, 1, 32, 32, 48))):
        y = m(torch.zeros(shape))
        print(type(m).__name__, count_parameters(m), tuple(y.shape))
