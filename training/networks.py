"""Small CNNs that predict needle likelihood maps, designed for CPU inference.

A strided stem, depthwise-separable blocks (a depthwise 3x3(x3) convolution then a pointwise
1x1(x1) one) with growing dilation for context, one skip connection at half resolution, and a
1x1 head with two output channels: shaft and tip logits. The output is at half the input's
resolution (``OUTPUT_STRIDE``); the runtime maps it back to the frame's grid. Inputs must have
sides divisible by ``INPUT_MULTIPLE`` (the runtime pads).

Optionally (``refine_blocks``, ``oriented_taps``; not used by the shipped models, see
docs/notes/volume-model.md) a refinement stage at half resolution re-reads the first stage's
features and maps, with one-sided sums along the 13 neighbour directions, and is trained with
the first stage supervised too.
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


def _directions(dims: int) -> list[tuple[int, ...]]:
    """One of each pair of opposite neighbour offsets: 4 in 2D, 13 in 3D."""
    import itertools

    out = []
    for d in itertools.product((-1, 0, 1), repeat=dims):
        if any(d) and d[next(i for i, v in enumerate(d) if v)] > 0:
            out.append(d)
    return out


class _OrientedSums(nn.Module):
    """One-sided means of a map along every neighbour direction: for each direction d, the
    mean over k = 1..taps of m(x + k d) (ahead) and of m(x - k d) (behind).

    A needle's tip is where a line of needle evidence stops. The image holds it (given the
    true axis, a change point of the voxel means along it finds the tip within 1 mm in 37 of
    the 40 held-out volumes at CR 2.0, 38 of them read against the tissue around the needle:
    ``needlenet.bench._models.axis_changepoint_tip``), but
    a small CNN would need an oriented filter for every direction to see it. These fixed sums
    give the refinement stage those orientations at no learned cost; what is summed (the
    first stage's maps) and how the sums are read are learned."""

    def __init__(self, dims: int, taps: int = 4):
        super().__init__()
        if taps < 1:
            raise ValueError(f"taps must be at least 1, got {taps}")
        self.dirs = _directions(dims)
        self.taps = taps
        # in the state dict, so a checkpoint says how it was built
        self.register_buffer("n_taps", torch.tensor(taps), persistent=True)

    @property
    def n_out(self) -> int:
        return 2 * len(self.dirs)

    def forward(self, m: torch.Tensor) -> torch.Tensor:
        # one zero pad of `taps` on every side; every shifted copy is then a slice with
        # constant bounds (no shape arithmetic in the exported graph)
        P = self.taps
        mp = nn.functional.pad(m, [P] * (2 * (m.ndim - 2)))

        def at(offset):  # m(x + offset), zero outside
            return mp[(slice(None), slice(None)) + tuple(
                slice(P + o, (o - P) or None) for o in offset)]

        out = []
        for d in self.dirs:
            for sign in (1, -1):  # ahead, behind
                acc = at(tuple(sign * v for v in d))
                for k in range(2, self.taps + 1):
                    acc = acc + at(tuple(sign * k * v for v in d))
                out.append(acc)
        return torch.cat(out, 1) * (1.0 / self.taps)


class _LocalContrast(nn.Module):
    """The input over its local mean: ``g / mean(g)`` over a cube (square) of side ``window``
    around each voxel, where ``g = x + offset`` is proportional to the grey level (``offset``
    undoes the intensity normalisation's shift) and zero outside a sector scan (left out of
    the mean, as is the padding at the borders).

    Why: a needle at Zhao's CR 2.0 is 1.4-1.5 times the tissue next to it where that tissue
    is brighter than average (docs/notes/volume-model.md), while inhomogeneous tissue varies
    over millimetres by more than that; the ratio to a 5 mm local mean takes the slow variation
    out. Measured on the held-out CR 2.0 volumes, the voxel AUC of a 0.5 mm-smoothed image is
    0.68-0.99 raw and 0.97-0.998 over its 5 mm local mean. Separable box means (three 1D
    average pools), so the cost is linear in the window."""

    def __init__(self, dims: int, window: int, offset: float):
        super().__init__()
        if window < 3 or window % 2 == 0:
            raise ValueError(f"local contrast window must be odd and at least 3, got {window}")
        pool = nn.AvgPool2d if dims == 2 else nn.AvgPool3d
        self.pools = nn.ModuleList()
        for ax in range(dims):
            k = tuple(window if a == ax else 1 for a in range(dims))
            pd = tuple(window // 2 if a == ax else 0 for a in range(dims))
            self.pools.append(pool(k, stride=1, padding=pd, count_include_pad=False))
        # in the state dict, so a checkpoint says how it was built
        self.register_buffer("window", torch.tensor(window), persistent=True)
        self.register_buffer("offset", torch.tensor(float(offset)), persistent=True)

    def _mean(self, a):
        for p in self.pools:
            a = p(a)
        return a

    def forward(self, x):
        g = torch.clamp(x + self.offset, min=0.0)
        inside = (g > 1e-6).to(g.dtype)
        ratio = g * self._mean(inside) / (self._mean(g) + 1e-3)
        return torch.cat([x, ratio - 1.0], 1)


class _NeedleNet(nn.Module):
    def __init__(self, dims: int, width: int = 16, in_channels: int = 1, out_channels: int = 2,
                 dilations: tuple[int, ...] = (1, 2, 4, 8), refine_blocks: int = 0,
                 oriented_taps: int = 0, refine_tip_only: bool = False,
                 local_window: int = 0, local_offset: float = 1.0):
        super().__init__()
        conv = nn.Conv2d if dims == 2 else nn.Conv3d
        bn = nn.BatchNorm2d if dims == 2 else nn.BatchNorm3d
        self.dims = dims
        # optional second input channel: the image over its local mean (_LocalContrast)
        self.local = _LocalContrast(dims, local_window, local_offset) if local_window else None
        n_in = in_channels * (2 if self.local is not None else 1)
        self.stem = nn.Sequential(conv(n_in, width, 3, stride=2, padding=1, bias=False),
                                  bn(width), nn.ReLU(inplace=True))  # 1/2
        self.block_half = _DSBlock(conv, bn, width, width)
        self.down = _DSBlock(conv, bn, width, 2 * width, stride=2)  # 1/4
        self.context = nn.Sequential(*[_DSBlock(conv, bn, 2 * width, 2 * width, dilation=d)
                                       for d in dilations])
        self.up_proj = nn.Sequential(conv(2 * width, width, 1, bias=False), bn(width))
        self.fuse = _DSBlock(conv, bn, width, width)
        self.head = conv(width, out_channels, 1)
        self.mode = "bilinear" if dims == 2 else "trilinear"
        # Optional refinement stage (stacked, with intermediate supervision, as in stacked
        # hourglass keypoint networks): it sees the first stage's features and its maps, so
        # it can follow a clean shaft map to where the needle ends instead of finding the
        # tip from the image alone.
        self.refine = None
        self.oriented = None
        if oriented_taps and not refine_blocks:
            raise ValueError("oriented_taps needs a refinement stage (refine_blocks >= 1)")
        if refine_blocks:
            n_in = width + out_channels
            if oriented_taps:
                self.oriented = _OrientedSums(dims, oriented_taps)
                # summed: the first stage's shaft probability and one learned image channel
                self.evidence = conv(width, 1, 1)
                n_in += 2 * self.oriented.n_out
            self.refine_in = nn.Sequential(conv(n_in, width, 1, bias=False),
                                           bn(width), nn.ReLU(inplace=True))
            self.refine = nn.Sequential(*[_DSBlock(conv, bn, width, width, dilation=2 ** i)
                                          for i in range(refine_blocks)])
            self.refine_head = conv(width, out_channels, 1)
            # tip only: the refinement reads the first stage without training it (detached)
            # and replaces only the tip channel, so the shaft map is the first stage's own
            self.register_buffer("tip_only", torch.tensor(int(refine_tip_only)))

    def forward(self, x, return_aux: bool = False):
        if self.local is not None:
            x = self.local(x)
        h = self.block_half(self.stem(x))
        c = self.context(self.down(h))
        u = nn.functional.interpolate(self.up_proj(c), size=h.shape[2:], mode=self.mode,
                                      align_corners=False)
        f = self.fuse(h + u)
        logits = self.head(f)  # logits at 1/2 resolution
        if self.refine is None:
            return (logits, []) if return_aux else logits
        tip_only = bool(self.tip_only)
        parts = [f.detach(), logits.detach()] if tip_only else [f, logits]
        if self.oriented is not None:
            ev = torch.cat([torch.sigmoid(parts[1][:, :1]), torch.tanh(self.evidence(parts[0]))],
                           1)
            parts.append(self.oriented(ev))
        out = self.refine_head(self.refine(self.refine_in(torch.cat(parts, 1))))
        if tip_only:
            out = torch.cat([logits[:, :1], out[:, 1:]], 1)
        return (out, [logits]) if return_aux else out


class NeedleNet2D(_NeedleNet):
    """For ``inplane`` and ``axial`` images: (N, 1, H, W) -> (N, 2, H/2, W/2) logits."""

    def __init__(self, width: int = 16, **kw):
        super().__init__(2, width=width, **kw)


class NeedleNet3D(_NeedleNet):
    """For volumes: (N, 1, D, H, W) -> (N, 2, D/2, H/2, W/2) logits."""

    def __init__(self, width: int = 8, **kw):
        super().__init__(3, width=width, dilations=kw.pop("dilations", (1, 2, 4)), **kw)


def build_network(modality: str, width: int | None = None, refine_blocks: int = 0,
                  oriented_taps: int = 0, refine_tip_only: bool = False,
                  local_window: int = 0, local_offset: float = 1.0) -> nn.Module:
    kw = {"refine_blocks": refine_blocks, "oriented_taps": oriented_taps,
          "refine_tip_only": refine_tip_only, "local_window": local_window,
          "local_offset": local_offset}
    if modality in ("inplane", "axial"):
        return NeedleNet2D(width=width or 16, **kw)
    if modality == "volume":
        return NeedleNet3D(width=width or 8, **kw)
    raise ValueError(f"unknown modality {modality!r}")


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def _check() -> None:  # pragma: no cover - a quick manual check
    for m, shape in ((NeedleNet2D(), (1, 1, 64, 96)), (NeedleNet3D(), (1, 1, 32, 32, 48))):
        y = m(torch.zeros(shape))
        print(type(m).__name__, count_parameters(m), tuple(y.shape))
