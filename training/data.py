"""Training data generated on the fly by ``synth``: endless, seeded, widely randomised.

Every world draws its scenario and imaging from one place (:func:`randomize`): insertion angles
and speeds, contrast, gauge, depth, inhomogeneous backgrounds with bright distractors, tissue
and probe motion, needles partly out of plane, frames with no needle at all, and the scanner
itself (centre frequency, bandwidth, f-numbers, foci, dynamic range, gain, TGC, noise, speckle
density, needle echo, reverberation, shadow), so that the model does not learn one simulator's
look. In-plane worlds go further (:func:`randomize_inplane`): needles from either side through
the skin or the lateral border at 3-85 degrees, gauges 14-25, specular or diffuse shafts with
or without reverberation tails, bright or dark bevels, 3-15 MHz, compounding, TGC curves, grey
maps, capture margins, sector masks, probe-face reverberation, interfaces parallel to the
needle, vessels, shadows and needle-free worlds, whose tissue stays still: the network sees one
frame at a time, where motion changes nothing but costs a fresh tissue image per frame. (The
narrow worlds keep the shipped model's recipe, tissue motion included.) Frames are resampled to
the model's spacing with the runtime's own function.

Targets (on the network's output grid, half the input resolution): shaft = a Gaussian of the
3D distance to the labelled centreline (sigma about the needle radius), tip = a Gaussian of the
distance to where the visible shaft ends (:func:`visible_end`). Distances are taken in the
probe frame in 3D, so a needle partly out of the image plane fades from the targets as it fades
from the image; pixels a display mask blacks out have no target.
"""

from __future__ import annotations

from dataclasses import dataclass

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset

import synth
from needlenet.features import (
    NORMALIZATIONS,
    frame_statistics,
    normalize,
    to_model_grid,
    wall_offsets,
)

from .networks import INPUT_MULTIPLE, OUTPUT_STRIDE
from .postprocess import draw_postprocessing, postprocessed
from .worlds import randomize, randomize_axial, randomize_inplane

__all__ = ["DataConfig", "randomize", "randomize_inplane", "randomize_axial", "make_targets",
           "visible_end", "target_reference", "wall_offsets", "SynthStream", "SynthDataModule",
           "sample_from_sequence", "prepare_frame",
           "validation_set", "simplify_polyline", "model_output_grid", "INTENSITY_MEAN",
           "INTENSITY_STD"]

# the "fixed" input normalisation: (uint8 / 255 - mean) / std, stored in the ONNX metadata
INTENSITY_MEAN = NORMALIZATIONS["fixed"]["mean"]
INTENSITY_STD = NORMALIZATIONS["fixed"]["std"]


INPLANE_WORLDS = ("wide", "narrow")


@dataclass(frozen=True)
class DataConfig:
    modality: str = "inplane"
    spacing_mm: float = 0.2  # the model's pixel/voxel spacing (isotropic)
    crop: int = 128  # input crop side (pixels/voxels at the model spacing)
    frames_per_world: int = 12
    shuffle_buffer: int = 96
    batch_size: int = 16
    seed: int = 0
    num_workers: int = 1
    val_frames: int = 64
    val_seed: int = 10_000_000  # validation worlds: seeds never used in training
    crops_per_frame: int = 1  # several random crops of one simulated frame (costly volumes)
    normalization: str = "fixed"  # a key of needlenet.features._resample.NORMALIZATIONS
    # volumes only: the share of worlds in Zhao mode (needle voxels drawn at a contrast ratio,
    # Zhao eq. 9) and the range of that ratio, drawn uniformly or (cr_log) log-uniformly
    zhao_fraction: float = 0.5
    cr_range: tuple[float, float] = (1.5, 5.0)
    cr_log: bool = False
    # in-plane only: "wide" worlds (randomize_inplane: every axis a scanner or insertion
    # varies; tip targets where the visible shaft ends) or "narrow" ones (a needle from the top
    # right at 15-70 degrees, no display masks, tip targets at the labelled tip: the worlds the
    # shipped in-plane model was trained on)
    inplane_worlds: str = "wide"
    # in-plane narrow worlds only: the share of them with a tissue boundary's specular echo
    # beside the needle (a needle-like line that is no needle; worlds.boundary_beside)
    inplane_boundaries: float = 0.0
    # volumes only: the share of Zhao-scenario worlds with a bright interface beside the needle
    # (worlds.interface_in_volume) and the share with no needle at all
    volume_interfaces: float = 0.0
    volume_needle_free: float = 0.0
    # in-plane only: held-out worlds over which the median speckle size, recorded in the
    # model's metadata, is measured (training/speckle.py)
    speckle_worlds: int = 200
    # in-plane only: the share of worlds whose frames pass through a scanner's post-processing
    # (speckle reduction, edge enhancement, JPEG; training/postprocess.py), one chain per world
    postprocess_fraction: float = 0.0

    def __post_init__(self):
        if self.inplane_worlds not in INPLANE_WORLDS:
            raise ValueError(f"inplane_worlds must be one of {', '.join(INPLANE_WORLDS)}, got "
                             f"{self.inplane_worlds!r}")
        if self.normalization not in NORMALIZATIONS:
            raise ValueError(f"normalization must be one of {', '.join(NORMALIZATIONS)}, got "
                             f"{self.normalization!r}")
        if not self.spacing_mm > 0:
            raise ValueError(f"spacing_mm must be positive, got {self.spacing_mm}")
        if self.crop < 2 * INPUT_MULTIPLE:
            raise ValueError(f"crop must be at least {2 * INPUT_MULTIPLE} pixels, got {self.crop}")
        for name in ("batch_size", "frames_per_world", "crops_per_frame", "val_frames",
                     "shuffle_buffer", "speckle_worlds"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.num_workers < 0:
            raise ValueError(f"num_workers must be 0 or more, got {self.num_workers}")
        for name in ("zhao_fraction", "inplane_boundaries", "postprocess_fraction",
                     "volume_interfaces", "volume_needle_free"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        lo, hi = (float(v) for v in self.cr_range)
        if not 1.05 <= lo <= hi <= 10.0:  # Zhao eq. 9's domain in synth
            raise ValueError("cr_range must satisfy 1.05 <= low <= high <= 10, got "
                             f"{tuple(self.cr_range)}")


# Where the targets sit across the needle. A linear probe sees a needle as the bright echo of
# its wall facing the transducer (and a bevel echo at that wall's end); the centre line lies a
# radius deeper, and the radius (the gauge) cannot be read reliably from the image. Trained on
# centre-line targets over gauges 14-22 a network marks a gauge-average depth below the echo
# (measured: 0.6 mm, so a 14 G centre line came out 0.4 mm too shallow and a 22 G one 0.3 mm
# too deep). So the 2D models mark the wall, which the image shows, and the trackers move it to
# the centre line with the needle radius they are given, as Carriere's classical tracker does.
# Volumes keep the centre line (Zhao mode fills the needle's cross-section).
WALL_REFERENCED = ("inplane", "axial")


def target_reference(modality: str) -> str:
    """``"wall"`` or ``"centerline"``: where the targets (and the exported maps) mark the
    needle; written into the ONNX metadata as ``target_reference``."""
    return "wall" if modality in WALL_REFERENCED else "centerline"


def simplify_polyline(poly: np.ndarray, tol_mm: float) -> np.ndarray:
    """The vertices of ``poly`` (K, D) that Ramer-Douglas-Peucker keeps at tolerance
    ``tol_mm``: every dropped vertex lies within ``tol_mm`` of the simplified polyline, so a
    distance to it is off by at most ``tol_mm``. A straight needle's 64 centre-line samples
    become 2 vertices (measured: in-plane targets 14 -> 3 ms per frame)."""
    poly = np.asarray(poly, float)
    if len(poly) <= 2:
        return poly
    keep = np.zeros(len(poly), bool)
    keep[[0, -1]] = True
    stack = [(0, len(poly) - 1)]
    while stack:  # one entry per kept vertex (a few for a bent needle), never per point
        i, j = stack.pop()
        if j - i < 2:
            continue
        d = synth.distance_to_polyline(poly[i + 1:j], poly[[i, j]])
        k = int(np.argmax(d))
        if d[k] > tol_mm:
            keep[i + 1 + k] = True
            stack += [(i, i + 1 + k), (i + 1 + k, j)]
    return poly[keep]


def _imaging(seq) -> synth.ImagingParams | None:
    d = seq.meta.get("imaging") if isinstance(seq.meta, dict) else None
    return synth.ImagingParams.from_dict(d) if d else None


def visible_end(seq, i: int, step_mm: float = 0.05) -> np.ndarray | None:
    """Where the visible shaft of an in-plane frame ends (probe frame, 3D), or None when no
    tip target applies.

    A centre-line point is visible where the frame shows it: inside the image and its display
    mask, and within half the elevation beam's FWHM plus the radius of the image plane (the
    criterion of synth's ``visible`` label). The visible shaft ends at the tip when the tip is
    visible; where the shaft fades out of the plane inside the image, it ends there (a tip as
    the image shows it). Where it leaves the image or the display mask, or nothing of it is
    visible, the frame has no tip target: the end there is the edge of the view, not a tip."""
    cl = np.asarray(seq.centerline_mm[i], float)
    seg = np.linalg.norm(np.diff(cl, axis=0), axis=1)
    length = float(seg.sum())
    if length < 0.2:
        return None
    s = np.concatenate([[0.0], np.cumsum(seg)])
    fine = np.arange(0.0, length + step_mm, step_mm).clip(max=length)
    pts = np.stack([np.interp(fine, s, cl[:, k]) for k in range(3)], -1)
    g = seq.grid()
    xz = pts[:, [0, 2]]
    view = g.contains(xz)
    params = _imaging(seq)
    if params is not None:
        mask = synth.display_mask(g, params)
        if mask is not None:
            ij = np.clip(np.rint(g.points_to_index(xz)).astype(int), 0,
                         np.asarray(g.shape) - 1)
            view &= mask[ij[:, 0], ij[:, 1]]
        radius = float(seq.meta.get("needle", {}).get("radius_mm", 0.5))
        half = 0.5 * 2.3548 * params.sigma_elevation_mm(np.maximum(pts[:, 2], 0.0)) + radius
        in_plane = np.abs(pts[:, 1]) <= half
    else:
        in_plane = np.ones(len(pts), bool)
    shown = view & in_plane
    if not shown.any():
        return None
    k = int(np.flatnonzero(shown)[-1])
    if k == len(pts) - 1:
        return pts[-1]
    return pts[k] if view[k + 1] else None  # faded out of the plane, or left the view


def _display_weight(seq, grid: synth.Grid, pts: np.ndarray) -> np.ndarray | None:
    """1 where the frame's display mask shows probe-frame points ``pts`` (x, 0, z), 0 where
    it blacks them out; None without a mask."""
    params = _imaging(seq)
    if params is None or seq.grid().ndim != 2:
        return None
    g = seq.grid()
    mask = synth.display_mask(g, params)
    if mask is None:
        return None
    ij = np.rint(g.points_to_index(pts[:, [0, 2]])).astype(int)
    ok = np.all((ij >= 0) & (ij < np.asarray(g.shape)), axis=1)
    w = np.zeros(len(pts), np.float32)
    w[ok] = mask[ij[ok, 0], ij[ok, 1]]
    return w


def make_targets(seq, i: int, grid: synth.Grid, reference: str | None = None,
                 visible_tip: bool = True) -> np.ndarray:
    """(2, *grid.shape) float32 targets on ``grid`` (the network's output grid) for frame i:
    shaft = a Gaussian of the distance to the needle (sigma the radius, at least 0.3 mm),
    tip = a Gaussian around its end: for in-plane frames (``visible_tip``), where the visible
    shaft ends (:func:`visible_end`; no tip target when it leaves the view), elsewhere (and for
    the "narrow" in-plane worlds) the labelled tip.
    Pixels a display mask blacks out have no target. ``reference`` (default
    :func:`target_reference` of the sequence's modality): ``"centerline"`` or ``"wall"`` (the
    wall facing the probe)."""
    radius = float(seq.meta.get("needle", {}).get("radius_mm", 0.5))
    reference = reference or target_reference(seq.modality)
    if reference not in ("wall", "centerline"):
        raise ValueError(f"reference must be 'wall' or 'centerline', got {reference!r}")
    sigma_shaft = max(radius, 0.3)
    sigma_tip = max(1.5 * grid.spacing_mm[0], 0.6)
    axes = np.meshgrid(*[grid.axis_coords(a) for a in range(grid.ndim)], indexing="ij")
    if grid.ndim == 2:  # (z, x) -> probe points (x, 0, z)
        pts = np.stack([axes[1].ravel(), np.zeros(axes[0].size), axes[0].ravel()], -1)
    else:
        pts = np.stack([axes[2].ravel(), axes[1].ravel(), axes[0].ravel()], -1)
    out = np.zeros((2, *grid.shape), np.float32)
    cl = np.asarray(seq.centerline_mm[i], float)
    length = float(np.linalg.norm(np.diff(cl, axis=0), axis=1).sum())
    if length < 0.2:  # the needle has not entered the tissue
        return out
    tip3 = np.asarray(seq.tip_3d_mm[i] if seq.tip_3d_mm is not None else seq.tip_mm[i], float)
    if seq.modality == "inplane" and visible_tip:
        tip3 = visible_end(seq, i)
        if tip3 is not None:
            tip3 = tip3 * np.array([1.0, 0.0, 1.0])  # the end as the image shows it
        params = _imaging(seq)
        if params is not None:
            # out of the plane the shaft fades as its echo does (synth's elevation weight
            # exp(-(|y| - r)^2 / 2 sigma_e^2)), not with the target's sigma: the elevation
            # offset beyond the radius is rescaled so the Gaussian below applies that weight
            sig_e = params.sigma_elevation_mm(np.maximum(cl[:, 2], 0.0))
            y = np.sign(cl[:, 1]) * np.maximum(np.abs(cl[:, 1]) - radius, 0.0)
            cl = cl.copy()
            cl[:, 1] = y * sigma_shaft / sig_e
    if reference == "wall":
        off = wall_offsets(cl, radius)
        if tip3 is not None:  # the wall offset at the nearest centre-line sample
            tip3 = tip3 + off[int(np.argmin(np.linalg.norm(cl - tip3, axis=1)))]
        cl = cl + off
    # targets vanish beyond 5 sigma: exact distances only for points in the needle's box
    near = np.all((pts >= cl.min(0) - 5 * sigma_shaft) & (pts <= cl.max(0) + 5 * sigma_shaft),
                  axis=1)
    d = np.full(len(pts), np.inf)
    d[near] = synth.distance_to_polyline(pts[near], simplify_polyline(cl, 1e-3))
    out[0] = np.exp(-0.5 * (d / sigma_shaft) ** 2).reshape(grid.shape)
    if tip3 is not None:
        dt = np.linalg.norm(pts - tip3[None], axis=1)
        out[1] = np.exp(-0.5 * (dt / sigma_tip) ** 2).reshape(grid.shape)
    if grid.ndim == 2:
        w = _display_weight(seq, grid, pts)
        if w is not None:
            out *= w.reshape(grid.shape)[None]
    return out


def prepare_frame(seq, i: int, cfg: DataConfig):
    """Frame i resampled to the model's spacing, and the whole frame's statistics for the
    normalisation (:func:`frame_statistics`; None for ``"fixed"``): computed once for the
    several crops of one frame."""
    g = seq.grid()
    img = to_model_grid(seq.images[i], g.spacing_mm, (cfg.spacing_mm,) * g.ndim)
    return img, frame_statistics(seq.images[i], NORMALIZATIONS[cfg.normalization])


def model_output_grid(frame_grid: synth.Grid, model_shape, lo, size) -> synth.Grid:
    """The grid of the network's output for the crop ``[lo, lo + size)`` of a frame resampled
    to ``model_shape`` by :func:`to_model_grid`.

    The resampler keeps pixel centres (OpenCV's half-pixel convention): model pixel j of an
    axis with n frame pixels at spacing s resampled to N lies at frame index
    (j + 1/2) n / N - 1/2, i.e. at ``origin + (e - s) / 2 + j e`` with the effective spacing
    e = s n / N (the model spacing up to the rounding of N), not at ``origin + j * model
    spacing`` (off by up to 0.2 mm on coarse training volumes). The output's stride-2 samples
    are centred on input pixel pairs (model index 2k + 1/2)."""
    s = np.asarray(frame_grid.spacing_mm, float)
    e = s * np.asarray(frame_grid.shape, float) / np.asarray(model_shape, float)
    origin = np.asarray(frame_grid.origin_mm, float) + 0.5 * (e - s)
    out_shape = tuple(int(n) // OUTPUT_STRIDE for n in size)
    return synth.Grid(out_shape, tuple(OUTPUT_STRIDE * e),
                      tuple(origin + (np.asarray(lo) + 0.5 * (OUTPUT_STRIDE - 1)) * e))


def sample_from_sequence(seq, i: int, cfg: DataConfig, rng: np.random.Generator | None,
                         crop: int | None = None, prepared=None):
    """(image (1, *S), target (2, *S/2), positive mask) at the model spacing.

    With ``rng`` a random crop of side ``crop`` (containing the needle 80% of the time when it
    is there) and random flips of the lateral axes; without, the whole frame, padded to the
    network's multiple. ``prepared``: :func:`prepare_frame` of this frame, when known.
    """
    g = seq.grid()
    sp = (cfg.spacing_mm,) * g.ndim
    img, level = prepared if prepared is not None else prepare_frame(seq, i, cfg)
    norm = NORMALIZATIONS[cfg.normalization]
    shape = np.asarray(img.shape)
    crop_n = crop if crop is not None else cfg.crop
    if rng is not None:
        size = np.minimum(shape, crop_n)
        size -= size % INPUT_MULTIPLE
        hi = shape - size
        if rng.random() < 0.8 and seq.visible is not None and seq.visible[i] and \
                seq.tip_mm is not None and np.all(np.isfinite(seq.tip_mm[i])):
            c = np.asarray(g.points_to_index(seq.tip_mm[i])) * np.asarray(g.spacing_mm) / sp
            c = c + rng.normal(0, 0.25 * size)
            lo = np.clip(np.rint(c - size / 2).astype(int), 0, hi)
        else:
            lo = np.array([int(rng.integers(0, h + 1)) for h in hi])
    else:
        size = shape + (-shape) % INPUT_MULTIPLE
        lo = np.zeros(g.ndim, int)
    sl = tuple(slice(int(a), int(a + n)) for a, n in zip(lo, size, strict=True))
    x = img[sl]
    if x.shape != tuple(int(n) for n in size):  # smaller than the crop: pad with edge values
        x = np.pad(x, [(0, int(n - m)) for n, m in zip(size, x.shape, strict=True)],
                   mode="edge")
    out_grid = model_output_grid(g, shape, lo, size)
    y = make_targets(seq, i, out_grid, visible_tip=cfg.inplane_worlds == "wide")
    if rng is not None:
        for ax in range(1, g.ndim):  # lateral (and elevation) flips keep the physics
            if rng.random() < 0.5:
                x = np.flip(x, ax)
                y = np.flip(y, ax + 1)
        # a frame smaller than the crop: padded to the crop's side (edge values, no target
        # outside the frame), so that every sample of a batch has one shape
        full = np.full(g.ndim, crop_n - crop_n % INPUT_MULTIPLE)
        if np.any(size < full):
            x = np.pad(x, [(0, int(n - m)) for n, m in zip(full, x.shape, strict=True)],
                       mode="edge")
            y = np.pad(y, [(0, 0)] + [(0, int(n // OUTPUT_STRIDE - m)) for n, m in
                                      zip(full, y.shape[1:], strict=True)])
    x = normalize(np.ascontiguousarray(x, np.float32), norm, level)
    return np.ascontiguousarray(x[None], np.float32), np.ascontiguousarray(y, np.float32)


class SynthStream(IterableDataset):
    """An endless, seeded stream of (image, target) samples from freshly simulated worlds.

    Each data-generating process draws its own worlds: the stream of process ``rank`` (the
    trainer's global rank under DDP) and DataLoader worker ``w`` is seeded with ``(seed, rank
    * workers + w)``, so no two processes of a run simulate the same world, and a one-process
    run (rank 0) draws what it always drew."""

    def __init__(self, cfg: DataConfig, rank: int = 0):
        self.cfg = cfg
        self.rank = int(rank)

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        wid = 0 if info is None else info.id
        stream = self.rank * max(self.cfg.num_workers, 1) + wid
        rng = np.random.default_rng([self.cfg.seed, stream])
        buf: list = []
        while True:
            name, kw = randomize(self.cfg.modality, rng, self.cfg)
            seed = int(rng.integers(0, self.cfg.val_seed))  # never a validation seed
            try:
                seq = synth.generate(name, seed=seed, frames=self.cfg.frames_per_world, **kw)
            except ValueError:
                continue  # a rare impossible draw (e.g. a needle that cannot fit): skip it
            if self.cfg.postprocess_fraction > 0 and self.cfg.modality == "inplane" and \
                    rng.random() < self.cfg.postprocess_fraction:
                seq.images = postprocessed(seq.images, seq.spacing_mm,
                                           draw_postprocessing(rng))
            for i in rng.permutation(seq.n_frames):
                prepared = prepare_frame(seq, int(i), self.cfg)
                for _ in range(self.cfg.crops_per_frame):
                    buf.append(sample_from_sequence(seq, int(i), self.cfg, rng,
                                                    prepared=prepared))
            while len(buf) > self.cfg.shuffle_buffer // 2:
                yield buf.pop(int(rng.integers(len(buf))))


def validation_set(cfg: DataConfig, n_frames: int | None = None, cr: float | None = None,
                   background: str = "inhomogeneous") -> list:
    """Held-out frames from worlds with seeds never used in training (whole frames)."""
    n = n_frames or cfg.val_frames
    rng = np.random.default_rng([cfg.val_seed, 1])
    out = []
    k = 0
    while len(out) < n:
        name, kw = randomize(cfg.modality, rng, cfg)
        kw["background"] = background
        if cr is not None and name == "volume":
            kw.update(zhao_mode=True, cr=cr)
        seq = synth.generate(name, seed=cfg.val_seed + k, frames=4, **kw)
        k += 1
        for i in range(seq.n_frames):
            x, y = sample_from_sequence(seq, i, cfg, rng, crop=cfg.crop)
            out.append((x, y))
    return out[:n]


class SynthDataModule(L.LightningDataModule):
    """Training batches from :class:`SynthStream`; validation on :func:`validation_set`."""

    def __init__(self, cfg: DataConfig):
        super().__init__()
        self.cfg = cfg
        self.val = None

    def setup(self, stage=None):
        if self.val is None:
            self.val = validation_set(self.cfg)

    def train_dataloader(self):
        kw = {}
        if self.cfg.num_workers > 0:
            # spawn, not fork: the parent already runs OpenMP (torch, numba), and forking a
            # process that did is unsafe
            kw = {"multiprocessing_context": "spawn", "persistent_workers": True}
        rank = self.trainer.global_rank if self.trainer is not None else 0
        return DataLoader(SynthStream(self.cfg, rank), batch_size=self.cfg.batch_size,
                          num_workers=self.cfg.num_workers, **kw)

    def val_dataloader(self):
        return DataLoader(self.val, batch_size=1)
