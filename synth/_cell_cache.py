"""The tissue a moving 3D probe sees, kept between volumes.

Imaging a volume directly generates every scatterer of the tissue-frame box around the probe's
view and evaluates the scattering map on them, volume after volume. Both depend on the
tissue alone: a cell's scatterers come from a counter-based generator, and the map lives in
the tissue frame. :class:`CellCache` generates the cells near the view once, with the map
applied to their amplitudes, and each volume then only moves the cached scatterers into the
probe frame and splats them (:mod:`synth._cell_kernels`), cell by cell in the same order as
the direct path, so the echo is the same to float rounding.

Memory: 16 bytes a scatterer (position as 3 float32, amplitude as float32), plus a slot map
of 4 bytes a cell of the held cells' bounding box and 24 bytes a slot. For the 128^3 moving
phantom (``volume-motion``: 100 scatterers per mm^3, 798 per 2 mm cell) one view needs 3,750
cells, 46 MiB; the cells near every view of a default sequence (76 volumes, 4 mm and 5 degrees
of motion), cached by :meth:`synth.Scanner.prepare`, are about 5,200 cells, 4.1 M scatterers,
64 MiB; a cache built around one view with the scanner's 4 mm pad (a servo loop, whose poses
are not known in advance) holds about 7,600 cells, 92 MiB, in slots for 25% more. The
scanner's bound, ``cell_cache_mb``, defaults to 256 MiB over all compounding looks.
"""

from __future__ import annotations

import numpy as np

from ._world import Tissue

__all__ = ["CellCache", "near_cells", "cache_bytes"]

BYTES_PER_SCATTERER = 16


def cache_bytes(n_cells: int, n_per_cell: int) -> int:
    """Memory of a cache of ``n_cells`` cells (the slot map aside)."""
    return int(n_cells) * int(n_per_cell) * BYTES_PER_SCATTERER


def near_cells(probe, tissue: Tissue, cells: np.ndarray, M: np.ndarray, lo, hi,
               pad_mm: float = 0.0) -> np.ndarray:
    """The cells (in the order given) whose scatterers, moved ``pad_mm`` or less, can reach
    the probe's beam grid (a sector probe) or the box [lo, hi) (a Cartesian probe) under the
    tissue-to-probe transform ``M``. Conservative: the test covers the cell's bounding
    sphere."""
    if len(cells) == 0:
        return cells
    centres = (cells + 0.5) * tissue.cell_mm
    reach = 0.5 * np.sqrt(3.0) * tissue.cell_mm + float(pad_mm) + 1e-3
    R = np.ascontiguousarray(M[:3, :3], dtype=np.float64)
    t = np.ascontiguousarray(M[:3, 3], dtype=np.float64)
    return cells[probe.cells_near(centres, reach, R, t, lo, hi)]


class CellCache:
    """The scatterers of a set of tissue cells, with the scattering map applied.

    Each cell has a slot of ``n_per_cell`` scatterers: positions in (3, N) float32 (one row
    per axis, so the per-volume pass reads them contiguously), amplitudes in (N,) float32. A
    slot map over the held cells' bounding box finds a cell's slot. :meth:`hold` moves the
    set of cells (a view that moves): cells kept stay in their slots, cells left free
    theirs, and only the cells entered are generated.
    """

    def __init__(self, tissue: Tissue, cells: np.ndarray, max_cells: int | None = None):
        self.tissue = tissue
        self.n_per_cell = tissue.n_per_cell
        self.xyz = np.empty((3, 0), np.float32)
        self.amp = np.empty(0, np.float32)
        self.slot_cell = np.zeros((0, 3), np.int64)  # the cell in each slot
        self.lo = np.zeros(3, np.int64)
        self.slot = np.full((1, 1, 1), -1, np.int32)
        self.hold(cells, max_cells)

    @property
    def n_cells(self) -> int:
        return int(np.count_nonzero(self.slot >= 0))

    @property
    def nbytes(self) -> int:
        return self.xyz.nbytes + self.amp.nbytes + self.slot.nbytes + self.slot_cell.nbytes

    def hold(self, cells: np.ndarray, max_cells: int | None = None) -> None:
        """Hold exactly ``cells`` (C, 3): keep those already held, generate the others into
        free slots. When there are too few, the arrays grow to 1.25 C slots (at most
        ``max_cells``, at least C), so that a view moving on finds free slots."""
        cells = np.ascontiguousarray(cells, dtype=np.int64).reshape(-1, 3)
        m = self.n_per_cell
        slots = self.lookup(cells)
        new = slots < 0
        free = np.ones(len(self.slot_cell), bool)
        free[slots[~new]] = False
        free = np.flatnonzero(free)
        if np.count_nonzero(new) > len(free):  # grow: the kept cells move to slots 0..k-1
            cap = int(1.25 * len(cells))
            cap = max(min(cap, max_cells) if max_cells is not None else cap, len(cells))
            k = int(np.count_nonzero(~new))
            xyz = np.empty((3, cap * m), np.float32)
            amp = np.empty(cap * m, np.float32)
            xyz.reshape(3, -1, m)[:, :k] = self.xyz.reshape(3, -1, m)[:, slots[~new]]
            amp.reshape(-1, m)[:k] = self.amp.reshape(-1, m)[slots[~new]]
            self.xyz, self.amp = xyz, amp
            self.slot_cell = np.zeros((cap, 3), np.int64)
            slots[~new] = np.arange(k)
            free = np.arange(k, cap)
        slots[new] = free[:np.count_nonzero(new)]
        if np.any(new):
            pos, a = self.tissue.cell_scatterers(cells[new])
            self.amp.reshape(-1, m)[slots[new]] = self.tissue.modulate(pos, a).reshape(-1, m)
            self.xyz.reshape(3, -1, m)[:, slots[new]] = pos.T.reshape(3, -1, m)
        self.slot_cell[slots] = cells
        self.lo = cells.min(0) if len(cells) else np.zeros(3, np.int64)
        shape = (cells.max(0) - self.lo + 1) if len(cells) else np.ones(3, np.int64)
        self.slot = np.full(tuple(int(v) for v in shape), -1, np.int32)
        self.slot[tuple((cells - self.lo).T)] = slots

    def lookup(self, cells: np.ndarray) -> np.ndarray:
        """Slots of ``cells`` (int64, in their order), -1 for those not held."""
        idx = cells - self.lo
        inside = np.all((idx >= 0) & (idx < np.asarray(self.slot.shape)), axis=1)
        out = np.full(len(cells), -1, np.int64)
        out[inside] = self.slot[tuple(idx[inside].T)]
        return out

    def slots(self, cells: np.ndarray) -> np.ndarray | None:
        """Slots of ``cells``, in their order; None if any of them is not held."""
        s = self.lookup(cells)
        return None if np.any(s < 0) else s

    def splat(self, probe, slots: np.ndarray, M: np.ndarray, lo, hi, two_k: float,
              out: np.ndarray) -> None:
        """Add the echo phasors of the cells ``slots`` under the tissue-to-probe transform
        ``M`` to the beam-grid IQ ``out`` (as the direct path's splat does; ``out`` may be
        float64, which sums faster than float32 and rounds once)."""
        R = np.ascontiguousarray(M[:3, :3], dtype=np.float64)
        t = np.ascontiguousarray(M[:3, 3], dtype=np.float64)
        probe.splat_cells(self.xyz, self.amp, slots, self.n_per_cell, R, t, lo, hi, two_k, out)
