"""Whole-frame needle line search on a 2D evidence map: a weighted Hough transform over the
map's strongest pixels, a weighted total-least-squares refinement, and the supported segment
along the line.

Nothing here assumes where the needle enters: every line direction in [0, 180) degrees and
every offset is searched (or a window around a prior line), so a needle from the left, the
right or the top edge, at any angle to the skin, is found the same way. The evidence map is
any non-negative needle likelihood (a learned shaft probability, or a classical line-contrast
map); ``level`` is the value that marks "needle" on it.

Geometry is in millimetres, point order (x lateral, z depth), on an isotropic working grid
(:func:`working_map`), so that angles and distances are physical.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numba
import numpy as np

from synth import Grid

from .._sampling import remap_points

__all__ = ["LineSearchParams", "NeedleLine", "WorkingMap", "working_map", "hough_peaks",
           "refine_line", "line_segment", "extend_end", "find_needle_line"]


@dataclass(frozen=True)
class LineSearchParams:
    """Settings of the search (units in the names).

    ``work_spacing_mm``: the isotropic grid the map is searched on (0.2 mm: finer than the
    echo of the thinnest needle, 25 G = 0.5 mm, and 4 times fewer pixels than a 0.1 mm frame).
    ``max_points``: the strongest pixels that vote. ``angle_step_deg`` and ``rho_bin_mm``:
    the Hough accumulator's resolution before refinement. ``peaks``: Hough peaks whose
    segments are compared (a long tissue line may out-vote a short needle). ``votes``: how
    often the peaks are voted, each time without the pixels of the lines rejected before.
    ``band_mm``: the half-widths of the two refinement passes (a 14 G needle's echo with its
    reverberations is about 2 mm thick). ``explained_mm``: pixels this close to a rejected
    line are set aside for the next vote (the needle's echo band, and the 2 mm by which two
    Hough peaks must differ). ``profile_half_width_mm``: the segment profile takes the maximum
    across this half-width, so that a line off by a pixel still reads the echo. ``gap_mm``:
    gaps of the needle's echo bridged along the line (a shaft partly out of the slice fades in
    places).
    """

    work_spacing_mm: float = 0.2
    max_points: int = 2000
    angle_step_deg: float = 2.0
    rho_bin_mm: float = 0.4
    peaks: int = 3
    votes: int = 3
    band_mm: tuple[float, float] = (1.5, 0.8)
    explained_mm: float = 2.0
    profile_half_width_mm: float = 0.4
    gap_mm: float = 2.0

    def __post_init__(self) -> None:
        for name in ("work_spacing_mm", "angle_step_deg", "rho_bin_mm", "gap_mm",
                     "explained_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("work_spacing_mm", "rho_bin_mm", "gap_mm", "explained_mm",
                     "profile_half_width_mm"):  # distances: a fraction of any image
            if not 0.0 <= getattr(self, name) <= 100.0:
                raise ValueError(f"{name} must lie in 0-100 mm, got {getattr(self, name)}")
        if self.max_points < 2 or self.peaks < 1 or self.votes < 1:
            raise ValueError("max_points must be >= 2, peaks and votes >= 1")


@dataclass(frozen=True)
class NeedleLine:
    """A supported line segment; false-valued when none was found (``reason`` says why).

    ``start_mm`` and ``end_mm`` are the segment's ends (x, z) with ``direction`` the unit
    vector from start to end (not yet oriented entry-to-tip); ``support`` the mean evidence
    over the segment; ``score`` its evidence summed along it (mm)."""

    found: bool
    reason: str = ""
    start_mm: np.ndarray | None = None
    end_mm: np.ndarray | None = None
    direction: np.ndarray | None = None
    support: float = 0.0
    score: float = 0.0
    profile: np.ndarray | None = field(default=None, repr=False)
    refused: NeedleLine | None = field(default=None, repr=False)
    # of a false-valued result: the strongest segment the validity test refused

    def __bool__(self) -> bool:
        return self.found

    @property
    def length_mm(self) -> float:
        return float(np.linalg.norm(self.end_mm - self.start_mm)) if self.found else 0.0

    def reversed(self) -> NeedleLine:
        return NeedleLine(True, "", self.end_mm, self.start_mm, -self.direction, self.support,
                          self.score, None if self.profile is None else self.profile[::-1])


@dataclass(frozen=True)
class WorkingMap:
    """An evidence map on an isotropic grid: ``values[i, j]`` lies at (x, z) =
    (x0 + j * step, z0 + i * step)."""

    values: np.ndarray
    x0: float
    z0: float
    step: float

    def points(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        return np.stack([self.x0 + cols * self.step, self.z0 + rows * self.step], axis=-1)

    def sample(self, pts: np.ndarray) -> np.ndarray:
        """Bilinear samples at points (..., 2) in mm; 0 outside the map."""
        p = np.asarray(pts, np.float32)
        return self.sample_xz(p[..., 0], p[..., 1])

    def sample_xz(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Bilinear samples at points given as two coordinate arrays (mm, any one shape); 0
        outside the map."""
        x, z = np.asarray(x, np.float32), np.asarray(z, np.float32)
        mx = ((x - self.x0) / self.step).astype(np.float32)
        my = ((z - self.z0) / self.step).astype(np.float32)
        return remap_points(self.values, mx, my)


def working_map(values: np.ndarray, grid: Grid, step_mm: float) -> WorkingMap:
    """``values`` (array order [z, x] on ``grid``) resampled to an isotropic ``step_mm`` grid
    (area averaging when shrinking). OpenCV keeps pixel centres: output pixel j sits at input
    index (j + 0.5) n / m - 0.5."""
    a = np.asarray(values, np.float32)
    nz, nx = a.shape
    dz, dx = (float(s) for s in grid.spacing_mm)
    mz = max(int(round(nz * dz / step_mm)), 2)
    mx = max(int(round(nx * dx / step_mm)), 2)
    if (mz, mx) != (nz, nx):
        interp = cv2.INTER_AREA if mz <= nz and mx <= nx else cv2.INTER_LINEAR
        a = cv2.resize(a, (mx, mz), interpolation=interp)
    sz, sx = nz / mz, nx / mx  # input pixels per output pixel
    oz, ox = (float(o) for o in grid.origin_mm)
    # the resampled grid is isotropic up to rounding: take the mean step
    step = 0.5 * (sz * dz + sx * dx)
    return WorkingMap(np.ascontiguousarray(a), ox + (0.5 * sx - 0.5) * dx,
                      oz + (0.5 * sz - 0.5) * dz, step)


_VOTE_BLOCK = 32768  # (point, direction) offsets computed and voted at once by hough_peaks


def _normal(theta: np.ndarray) -> np.ndarray:
    """Unit normals (-sin, cos) of line directions (cos, sin), theta in radians."""
    return np.stack([-np.sin(theta), np.cos(theta)], axis=-1)


def hough_peaks(pts: np.ndarray, w: np.ndarray, thetas_rad: np.ndarray, rho_bin_mm: float,
                n_peaks: int, rho_window: tuple[float, float] | None = None,
                min_separation: tuple[float, float] = (np.deg2rad(5.0), 2.0)) -> np.ndarray:
    """The ``n_peaks`` strongest lines {p : p . n(theta) = rho} of a weighted Hough transform
    of points ``pts`` (N, 2) with weights ``w``: rows (theta, rho, votes), strongest first.
    Votes are summed over three adjacent rho bins, so a line on a bin edge is not split.
    Peaks closer than ``min_separation`` (radians, mm) to a stronger one are skipped."""
    thetas = np.asarray(thetas_rad, float)
    normals = _normal(thetas).T.astype(np.float32)
    p32, w32 = pts.astype(np.float32), np.asarray(w, np.float32)
    # the lines' offsets rho are computed and voted a block of directions at a time: a few
    # hundred kB of temporaries instead of megabytes for all (points, directions)
    step = max(_VOTE_BLOCK // max(len(p32), 1), 1)
    blocks = [(a0, p32 @ normals[:, a0:a0 + step]) for a0 in range(0, len(thetas), step)]
    if rho_window is None:
        lo = min(float(r.min()) for _, r in blocks)
        hi = max(float(r.max()) for _, r in blocks)
    else:
        lo, hi = float(rho_window[0]), float(rho_window[1])
    n_bins = max(int(np.ceil((hi - lo) / rho_bin_mm)) + 1, 1)
    acc = np.zeros((len(thetas), n_bins))
    for a0, rho in blocks:  # the votes inside the window (decided on the bin, as counted)
        _vote(rho, w32, lo, 1.0 / rho_bin_mm, acc[a0:a0 + rho.shape[1]])
    acc = _box3(acc)
    flat_acc = acc.ravel()
    order = np.flatnonzero(flat_acc > 0)  # most cells are empty (and slow to partition)
    top = min(50 * n_peaks, order.size)  # the strongest cells only: n_peaks separated maxima
    order = order[np.argpartition(flat_acc[order], order.size - top)[order.size - top:]]
    order = order[np.argsort(flat_acc[order])[::-1]]
    out: list[tuple[float, float, float]] = []
    for flat in order:
        ia, ib = divmod(int(flat), n_bins)
        th, r = float(thetas[ia]), lo + (ib + 0.5) * rho_bin_mm
        if all(abs(_angle_diff(th, t0)) > min_separation[0] or abs(r - r0) > min_separation[1]
               for t0, r0, _ in out):
            out.append((th, r, float(acc[ia, ib])))
            if len(out) == n_peaks:
                break
    return np.asarray(out, float).reshape(-1, 3)


@numba.njit(cache=True, nogil=True)
def _vote(rho, w, lo, inv, acc):  # pragma: no cover - compiled
    """acc[a, b] += w[i] for each point i and direction a, b = floor((rho[i, a] - lo) * inv)
    in float32 (numpy's arithmetic on these arrays), votes outside acc's bins skipped; each
    bin sums its votes in point order, as ``np.bincount`` does (the same sums to the bit,
    without its (points, directions) index and weight arrays)."""
    n, k = rho.shape
    n_bins = acc.shape[1]
    lo32, inv32 = np.float32(lo), np.float32(inv)
    for i in range(n):
        wi = np.float64(w[i])
        for a in range(k):
            b = int(np.floor((rho[i, a] - lo32) * inv32))
            if 0 <= b < n_bins:
                acc[a, b] += wi


@numba.njit(cache=True, nogil=True)
def _box3(acc):  # pragma: no cover - compiled
    """The sum of each cell and its two neighbours along each row (0 past the ends), as
    ``uniform_filter1d(acc, 3, axis=1, mode="constant") * 3.0`` gives it to the bit: scipy's
    running sum along the row (the sample entering less the one leaving, added at each
    step), divided by 3, times 3."""
    n, m = acc.shape
    out = np.empty_like(acc)
    for a in range(n):
        tmp = 0.0
        tmp += 0.0
        tmp += acc[a, 0]
        if m > 1:
            tmp += acc[a, 1]
        out[a, 0] = tmp / 3.0 * 3.0
        for k in range(1, m):
            enter = acc[a, k + 1] if k + 1 < m else 0.0
            leave = acc[a, k - 2] if k >= 2 else 0.0
            tmp += enter - leave
            out[a, k] = tmp / 3.0 * 3.0
    return out


def _angle_diff(a: float, b: float) -> float:
    """a - b for line directions (modulo pi), in (-pi/2, pi/2]."""
    return float((a - b + np.pi / 2) % np.pi - np.pi / 2)


def refine_line(pts: np.ndarray, w: np.ndarray, theta: float, rho: float,
                bands_mm) -> tuple[np.ndarray, np.ndarray] | None:
    """Weighted total least squares of the points within each band (mm) of the line in turn:
    (centroid, unit direction), or None when fewer than two points support it."""
    c, d = np.zeros(2), np.array([np.cos(theta), np.sin(theta)])
    ok = _refine(np.ascontiguousarray(pts[:, 0], dtype=float),
                 np.ascontiguousarray(pts[:, 1], dtype=float), np.ascontiguousarray(w, dtype=float),
                 float(rho), np.asarray(bands_mm, float).reshape(-1), c, d)
    return (c, d) if ok else None


@numba.njit(cache=True, nogil=True)
def _refine(x, z, w, rho, bands, c, d):  # pragma: no cover - compiled
    """:func:`refine_line` on coordinate vectors ``x``, ``z``: ``d`` holds the Hough line's
    direction on entry; the centroid and unit direction are written into ``c`` and ``d``.
    The first band lies about the Hough line (offset ``rho``), each next one about the fit
    before; each pass takes the weighted centroid of the points in its band, then their
    moments about it. False when a band holds fewer than two points or no positive weight."""
    n0, n1 = -d[1], d[0]
    for band in bands:
        sw = sx = sz = 0.0
        k = 0
        for i in range(x.size):
            if abs(x[i] * n0 + z[i] * n1 - rho) <= band:
                sw += w[i]
                sx += w[i] * x[i]
                sz += w[i] * z[i]
                k += 1
        if k < 2 or not sw > 0:
            return False
        cx, cz = sx / sw, sz / sw
        sxx = sxz = szz = 0.0
        for i in range(x.size):
            if abs(x[i] * n0 + z[i] * n1 - rho) <= band:
                qx, qz = x[i] - cx, z[i] - cz
                sxx += w[i] * qx * qx
                sxz += w[i] * qx * qz
                szz += w[i] * qz * qz
        cov = np.empty((2, 2))
        cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1] = sxx / sw, sxz / sw, sxz / sw, szz / sw
        axis = np.linalg.eigh(cov)[1][:, 1]  # LAPACK's, as numpy's eigh gives it
        norm = np.sqrt(axis[0] ** 2 + axis[1] ** 2)
        c[0], c[1] = cx, cz
        d[0], d[1] = axis[0] / norm, axis[1] / norm
        n0, n1 = -d[1], d[0]
        rho = cx * n0 + cz * n1
    return True


def _clip_to_box(c: np.ndarray, d: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Parameters (t0, t1) of the line c + t d inside the box [lo, hi], or None."""
    t0, t1 = -np.inf, np.inf
    for k in range(len(d)):  # the slab of each axis: where the line lies between its faces
        if d[k] != 0:
            a, b = (lo[k] - c[k]) / d[k], (hi[k] - c[k]) / d[k]
            t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
        elif not lo[k] <= c[k] <= hi[k]:
            return None  # parallel to the slab's faces, outside it
    return (float(t0), float(t1)) if t1 > t0 else None


def line_segment(wm: WorkingMap, c: np.ndarray, d: np.ndarray, level: float,
                 params: LineSearchParams) -> NeedleLine:
    """The best supported segment of the map along the line c + t d: the profile (maximum
    across ``profile_half_width_mm``) thresholded at ``level``, gaps up to ``gap_mm`` closed,
    and the run with the largest evidence sum. Its ends sit where the profile crosses
    ``level`` (linear interpolation)."""
    span = _span(wm, c, d)
    if span is None:
        return NeedleLine(False, "the line misses the image")
    step = wm.step
    t = np.arange(span[0], span[1] + 1e-9, step)
    if len(t) < 2:
        return NeedleLine(False, "the line crosses the image in less than two samples")
    prof = _profile(wm, c, d, t, params)
    # the level in the profile's type, as numpy compares an array with a Python float
    i0, i1, total = _best_run(prof, prof.dtype.type(level),
                              max(int(round(params.gap_mm / step)), 1))
    if i0 < 0:
        return NeedleLine(False, f"no evidence above {level:g} along the line", profile=prof)
    t0, t1 = _crossing(t, prof, i0, -1, level), _crossing(t, prof, i1, +1, level)
    support = float(prof[i0:i1 + 1].mean())
    return NeedleLine(True, "", c + t0 * d, c + t1 * d, d.copy(), support, total * step,
                      prof[i0:i1 + 1])


@numba.njit(cache=True, nogil=True)
def _best_run(prof, level, gap):  # pragma: no cover - compiled
    """The run of ``prof`` at or above ``level``, gaps of up to ``gap`` samples bridged (a
    binary closing with a ``gap + 1``-sample element), with the largest sum of the profile
    over it (its bridged gaps included; the first of equal sums): (first index, last index,
    sum), or (-1, -1, 0.0) when no sample reaches the level. Sums in float64 in index
    order."""
    best0, best1, best = -1, -1, 0.0
    i, n = 0, prof.size
    while i < n:
        if prof[i] < level:
            i += 1
            continue
        first = last = i
        j = i + 1
        while j < n and j - last <= gap + 1:
            if prof[j] >= level:
                last = j
            j += 1
        total = 0.0
        for k in range(first, last + 1):
            total += np.float64(prof[k])
        if best0 < 0 or total > best:
            best0, best1, best = first, last, total
        i = last + 1
    return best0, best1, best


def extend_end(wm: WorkingMap, seg: NeedleLine, level: float,
               params: LineSearchParams) -> NeedleLine:
    """``seg`` with its end (``end_mm``, the tip end once oriented) moved on along its line
    while the map's profile stays at or above ``level``, gaps up to ``gap_mm`` closed: weaker
    evidence counts where it continues a segment found on strong evidence (Canny's
    hysteresis). The new end sits where the profile crosses ``level``; ``support`` and
    ``score`` stay those of ``seg``."""
    d = seg.direction
    span = _span(wm, seg.end_mm, d)
    if span is None or span[1] <= wm.step:
        return seg
    t = np.arange(0.0, span[1] + 1e-9, wm.step)
    prof = _profile(wm, seg.end_mm, d, t, params)
    on = np.flatnonzero(prof >= level)
    on = on[on > 0]
    g = max(int(round(params.gap_mm / wm.step)), 1)
    # samples at the level, from the segment's own end (sample 0) on, up to the first gap
    # longer than gap_mm
    runs = np.diff(np.concatenate([[0], on])) - 1
    wide = np.flatnonzero(runs > g)
    on = on[:wide[0]] if wide.size else on
    if on.size == 0:
        return seg
    last = int(on[-1])
    t1 = _crossing(t, prof, last, +1, level)
    return NeedleLine(True, "", seg.start_mm.copy(), seg.end_mm + t1 * d, d.copy(),
                      seg.support, seg.score, seg.profile)


def _span(wm: WorkingMap, c: np.ndarray, d: np.ndarray):
    """Parameters (t0, t1) of the line c + t d inside the map, or None."""
    h, w_ = wm.values.shape
    lo = np.array([wm.x0, wm.z0])
    return _clip_to_box(c, d, lo, lo + wm.step * np.array([w_ - 1, h - 1]))


def _profile(wm: WorkingMap, c: np.ndarray, d: np.ndarray, t: np.ndarray,
             params: LineSearchParams) -> np.ndarray:
    """The map along c + t d, the maximum across ``profile_half_width_mm``."""
    n = np.array([-d[1], d[0]])
    k = max(int(round(params.profile_half_width_mm / wm.step)), 0)
    offs = np.arange(-k, k + 1) * wm.step
    # each coordinate on its own: no (K, T, 2) points
    return wm.sample_xz(c[0] + t[None, :] * d[0] + offs[:, None] * n[0],
                        c[1] + t[None, :] * d[1] + offs[:, None] * n[1]).max(axis=0)


def _crossing(t: np.ndarray, prof: np.ndarray, i: int, side: int, level: float) -> float:
    """Where the profile crosses ``level`` between sample i (on) and its neighbour i + side."""
    j = i + side
    if not 0 <= j < len(prof) or prof[j] >= prof[i]:
        return float(t[i])
    frac = (prof[i] - level) / max(prof[i] - prof[j], 1e-12)
    return float(t[i] + side * min(max(frac, 0.0), 1.0) * (t[1] - t[0]))


def find_needle_line(wm: WorkingMap, level: float, params: LineSearchParams,
                     thetas_rad: np.ndarray | None = None,
                     prior: tuple[np.ndarray, float] | None = None,
                     is_valid=None, priority=None) -> NeedleLine:
    """The best needle segment on the map: Hough peaks over the pixels at or above half of
    ``level`` (the strongest ``max_points`` of them), each refined and read along its line;
    the segment with the largest evidence sum wins. When every segment read is rejected by
    ``is_valid``, the pixels within ``explained_mm`` of their lines are set aside and the
    lines are voted again from the rest, up to ``votes`` times (the progressive Hough
    transform of Matas et al. 2000 removes a found line's points the same way): a broad bright
    interface that holds most of the strongest pixels, and so every peak of one vote, does
    not hide a needle beside it.

    ``thetas_rad``: the line directions searched (default every ``angle_step_deg`` in [0,
    pi)). ``prior``: (point, rho half-window mm): search only lines within that offset of
    the point, at the given directions. ``is_valid``: a function of a
    segment that returns '' to accept it or the reason it is no needle (scikit-image's
    ``is_model_valid``); a rejected segment does not compete, and when every one is rejected
    the result is false-valued with the strongest one's reason. ``priority``: a function of a
    segment giving a number; a segment of higher priority wins over any of lower priority,
    and the evidence sum decides between equals."""
    p = params
    v = wm.values
    cand = np.flatnonzero(v.ravel() >= 0.5 * level)
    if cand.size < 2:
        return NeedleLine(False, f"fewer than two pixels at or above {0.5 * level:g}")
    rows, cols = np.divmod(cand, v.shape[1])
    pts_all = wm.points(rows.astype(float), cols.astype(float))
    vals_all = v.ravel()[cand]
    if thetas_rad is None:
        thetas_rad = np.deg2rad(np.arange(0.0, 180.0, p.angle_step_deg))
    thetas_rad = np.asarray(thetas_rad, float)
    window = None
    if prior is not None:
        c0, half = prior
        r0 = np.asarray(c0, float) @ _normal(thetas_rad).T
        window = (float(r0.min()) - half, float(r0.max()) + half)

    def rank(seg):
        return (priority(seg) if priority is not None else 0, seg.score)

    best = NeedleLine(False, "no Hough peak")
    rejected = None
    left = np.ones(len(cand), bool)  # pixels no rejected line explains
    for _ in range(p.votes):
        idx = np.flatnonzero(left)
        if idx.size < 2:
            break
        if idx.size > p.max_points:
            idx = idx[np.argpartition(vals_all[idx], -p.max_points)[-p.max_points:]]
        pts, vals = pts_all[idx], vals_all[idx].astype(float)
        for th, rho, _ in hough_peaks(pts, vals, thetas_rad, p.rho_bin_mm, p.peaks, window):
            fit = refine_line(pts, vals, th, rho, p.band_mm)
            if fit is None:
                continue
            seg = line_segment(wm, fit[0], fit[1], level, p)
            why = is_valid(seg) if seg and is_valid is not None else ""
            if why:
                if rejected is None or seg.score > rejected[0].score:
                    rejected = (seg, why)
                off = np.abs((pts_all - fit[0]) @ np.array([-fit[1][1], fit[1][0]]))
                left &= off > p.explained_mm
            elif seg and (not best or rank(seg) > rank(best)):
                best = seg
            elif not best and not seg:
                best = seg
        if best or rejected is None:
            break
    if not best and rejected is not None:
        return NeedleLine(False, rejected[1], profile=rejected[0].profile, refused=rejected[0])
    return best
