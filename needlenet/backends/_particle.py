"""Particle filters: resamplers, a generic bootstrap filter and Mathiassen's tip filter.

The generic filter is the sequential importance resampling filter of Arulampalam et al. 2002
("A tutorial on particle filters...", the "generic PF" that Mathiassen 2017 cites as [23]):
the prior is the importance density, so the weights are multiplied by the likelihood, and the
particles are resampled when the effective sample size drops below a threshold.

Resamplers are pure functions ``(weights, rng) -> indexes`` vectorised with
``np.searchsorted`` (FilterPy's ``filterpy.monte_carlo`` resamplers without their global random
state and per-particle loops). Every returned index array is sorted.

``MathiassenTipParticleFilter`` is the tip filter of Mathiassen 2017 (IEEE TCST), section II-D
and Algorithm 5: the state is [tip position along the needle axis (px), tip velocity (px/s)]
with the constant-velocity model of eq. (11); the measurement is the whole tip feature h(x)
along the axis turned into a density h_pdf (eqs. (20)-(21)) and read at each particle by linear
interpolation (eq. (22)), optionally times a Gaussian robot-velocity likelihood (eq. (23)).
Section III-B gives the parameters; they are the defaults of ``MathiassenPFParams``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "RngLike",
    "UpdateOutcome",
    "systematic_resample",
    "stratified_resample",
    "multinomial_resample",
    "residual_resample",
    "effective_sample_size",
    "ParticleFilter",
    "h_pdf",
    "MathiassenPFParams",
    "TipEstimate",
    "MathiassenTipParticleFilter",
]

RngLike = np.random.Generator | int | None
Resampler = Callable[[np.ndarray, RngLike], np.ndarray]


# --------------------------------------------------------------------------------------------
# Resampling
# --------------------------------------------------------------------------------------------


def _normalised_weights(weights) -> np.ndarray:
    """Validate a 1-D weight vector and return it scaled to sum to one."""
    w = np.asarray(weights, dtype=float)
    if w.ndim != 1 or w.size == 0:
        raise ValueError(f"weights must be a non-empty 1-D array, got shape {w.shape}")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError("weights must be finite and non-negative")
    total = w.sum()
    if total <= 0:
        raise ValueError("weights must not all be zero")
    return w / total


def _cumulative(w: np.ndarray) -> np.ndarray:
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0  # guard against round-off: every position in [0, 1) finds a bin
    return cumulative


def _pick(w: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Index j of the first bin with cumsum[j] > position (FilterPy's ``positions[i] <
    cumulative_sum[j]`` loop, done by one binary search per position)."""
    return np.searchsorted(_cumulative(w), positions, side="right").astype(np.intp)


def systematic_resample(weights, rng: RngLike = None) -> np.ndarray:
    """Systematic resampling: one uniform offset u, positions (u + i) / N.

    Each index i is drawn floor(N w_i) or ceil(N w_i) times. Mathiassen 2017, section II-D,
    uses this resampler. Returns sorted indexes of shape (N,).
    """
    w = _normalised_weights(weights)
    n = w.size
    rng = np.random.default_rng(rng)
    positions = (rng.random() + np.arange(n)) / n
    return _pick(w, positions)


def stratified_resample(weights, rng: RngLike = None) -> np.ndarray:
    """Stratified resampling: one uniform draw in each of the N strata [i/N, (i+1)/N)."""
    w = _normalised_weights(weights)
    n = w.size
    rng = np.random.default_rng(rng)
    positions = (rng.random(n) + np.arange(n)) / n
    return _pick(w, positions)


def multinomial_resample(weights, rng: RngLike = None) -> np.ndarray:
    """Multinomial resampling: N independent draws from the categorical distribution w.

    The uniform draws are sorted first, so the indexes come out sorted; the multiset of
    indexes has the same distribution as with unsorted draws.
    """
    w = _normalised_weights(weights)
    rng = np.random.default_rng(rng)
    return _pick(w, np.sort(rng.random(w.size)))


def residual_resample(weights, rng: RngLike = None) -> np.ndarray:
    """Residual resampling (Liu & Chen 1998): floor(N w_i) deterministic copies of each index,
    the remaining N - sum floor(N w_i) drawn from the residuals N w_i - floor(N w_i).

    The residual part is drawn by systematic resampling (the "residual-systematic" variant)
    rather than FilterPy's multinomial draw, so each index is drawn floor(N w_i) or
    ceil(N w_i) times, as with ``systematic_resample``.
    """
    w = _normalised_weights(weights)
    n = w.size
    rng = np.random.default_rng(rng)
    scaled = n * w
    copies = np.floor(scaled).astype(np.intp)
    deterministic = np.repeat(np.arange(n), copies)
    n_left = n - deterministic.size
    if n_left == 0:
        return deterministic
    residual = scaled - copies  # in [0, 1), sums to n_left
    positions = (rng.random() + np.arange(n_left)) / n_left
    drawn = _pick(residual / residual.sum(), positions)
    return np.sort(np.concatenate([deterministic, drawn]))


def effective_sample_size(weights) -> float:
    """N_eff = 1 / sum_i w_i^2 of the normalised weights (Arulampalam 2002, eq. (51))."""
    w = _normalised_weights(weights)
    return float(1.0 / np.sum(w * w))


# --------------------------------------------------------------------------------------------
# Generic particle filter
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UpdateOutcome:
    """Result of a measurement update; false-valued when the measurement was not used.

    ``reason`` says why (for example every particle had zero likelihood).
    """

    ok: bool
    reason: str = ""
    resampled: bool = False
    ess: float = float("nan")

    def __bool__(self) -> bool:
        return self.ok


class ParticleFilter:
    """Bootstrap (SIR) particle filter over an (N, D) particle array.

    Parameters
    ----------
    particles : (N, D) array
        Initial particles (copied). A 1-D array is taken as N particles of dimension 1.
    weights : (N,) array, optional
        Initial weights (normalised); uniform by default.
    resampler : callable ``(weights, rng) -> indexes``
        Default ``systematic_resample``.
    resample_threshold : float
        Resample when N_eff < resample_threshold * N (1.0: resample at every update whose
        weights are not exactly uniform; 0.0: never).
    rng : Generator, int or None
        Generator used by ``predict`` and ``update`` when they are not given one.
    """

    def __init__(
        self,
        particles,
        weights=None,
        *,
        resampler: Resampler = systematic_resample,
        resample_threshold: float = 0.5,
        rng: RngLike = None,
    ) -> None:
        x = np.array(particles, dtype=float)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2 or x.shape[0] == 0:
            raise ValueError(f"particles must be an (N, D) array, got shape {x.shape}")
        if not 0.0 <= resample_threshold <= 1.0:
            raise ValueError(f"resample_threshold must lie in [0, 1], got {resample_threshold}")
        n = x.shape[0]
        if weights is None:
            w = np.full(n, 1.0 / n)
        else:
            w = _normalised_weights(weights)
            if w.size != n:
                raise ValueError(f"got {w.size} weights for {n} particles")
        self.particles = x
        self.weights = w
        self.resampler = resampler
        self.resample_threshold = float(resample_threshold)
        self.rng = np.random.default_rng(rng)

    @property
    def n_particles(self) -> int:
        return self.particles.shape[0]

    @property
    def ess(self) -> float:
        """Effective sample size of the current weights."""
        return effective_sample_size(self.weights)

    def predict(
        self,
        transition_fn: Callable[[np.ndarray, np.random.Generator], np.ndarray],
        rng: RngLike = None,
    ) -> None:
        """Propagate every particle: particles <- transition_fn(particles, rng), (N, D) in
        and out. The prior is the importance density, so the weights do not change."""
        rng = self.rng if rng is None else np.random.default_rng(rng)
        new = np.asarray(transition_fn(self.particles, rng), dtype=float)
        if new.shape != self.particles.shape:
            raise ValueError(
                f"transition_fn returned shape {new.shape}, expected {self.particles.shape}"
            )
        self.particles = new

    def update(
        self,
        likelihood_fn: Callable[[np.ndarray], np.ndarray],
        rng: RngLike = None,
        *,
        log: bool = False,
    ) -> UpdateOutcome:
        """Multiply the weights by p(z | x_i) = likelihood_fn(particles), shape (N,), and
        resample when N_eff < resample_threshold * N.

        With ``log=True`` the function returns log-likelihoods; the product is then formed in
        the log domain so that sharp likelihoods do not underflow. When every particle has
        zero likelihood the weights are left as they were and a false outcome is returned.
        """
        values = np.asarray(likelihood_fn(self.particles), dtype=float)
        if values.shape != (self.n_particles,):
            raise ValueError(
                f"likelihood_fn returned shape {values.shape}, expected ({self.n_particles},)"
            )
        with np.errstate(divide="ignore"):
            log_w = np.log(self.weights)
            if log:
                log_w = log_w + values
            else:
                if np.any(values < 0):
                    raise ValueError("likelihood values must be non-negative")
                log_w = log_w + np.log(values)
        log_w = np.where(np.isnan(log_w), -np.inf, log_w)
        top = np.max(log_w)
        if not np.isfinite(top):
            return UpdateOutcome(False, "every particle has zero likelihood", ess=self.ess)
        w = np.exp(log_w - top)
        self.weights = w / w.sum()
        ess = self.ess
        resampled = False
        if ess < self.resample_threshold * self.n_particles:
            self.resample(rng)
            resampled = True
        return UpdateOutcome(True, "", resampled=resampled, ess=ess)

    def resample(self, rng: RngLike = None) -> None:
        """Draw N particles with ``resampler`` and reset the weights to 1/N."""
        rng = self.rng if rng is None else np.random.default_rng(rng)
        indexes = self.resampler(self.weights, rng)
        self.particles = self.particles[indexes]
        self.weights = np.full(self.n_particles, 1.0 / self.n_particles)

    @property
    def mean(self) -> np.ndarray:
        """Weighted mean, shape (D,)."""
        return self.weights @ self.particles

    @property
    def covariance(self) -> np.ndarray:
        """Weighted covariance sum_i w_i (x_i - mean)(x_i - mean)^T, shape (D, D)."""
        d = self.particles - self.mean
        return (d * self.weights[:, None]).T @ d

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """(weighted mean (D,), weighted covariance (D, D))."""
        return self.mean, self.covariance


# --------------------------------------------------------------------------------------------
# Mathiassen 2017, section II-D
# --------------------------------------------------------------------------------------------


def h_pdf(h_values, axis_positions_px, x_bar_px: float, sigma_s_px: float) -> np.ndarray:
    """Mathiassen 2017, eqs. (20)-(21): the tip feature h(x) along the axis as a density.

    h_mod(x) = (h(x) - min_x h(x)) N(x; x_bar, sigma_s^2) and h_pdf = h_mod / sum_x h_mod, so
    the values are non-negative and sum to one over the sampled axis positions (with the
    paper's one sample per pixel the sum is the integral). The Gaussian's constant factor
    cancels in eq. (20) and is left out, and its exponent is shifted by its maximum over the
    axis so that a prediction far off the axis cannot underflow every sample to zero.
    If h is constant (or NaN) the feature carries no information and the uniform density over
    the axis is returned.

    Parameters
    ----------
    h_values : (L,) array
        h(x) of eq. (6) at each axis position.
    axis_positions_px : (L,) array
        Positions x along the needle axis (px), strictly increasing.
    x_bar_px : float
        Current estimate of the tip position (px), the centre of the Gaussian in eq. (21).
    sigma_s_px : float
        sigma_s of eq. (21), px (150 for PF, 75 for PF_v in section III-B).
    """
    h, x = _check_axis(h_values, axis_positions_px)
    if not sigma_s_px > 0:
        raise ValueError(f"sigma_s_px must be positive, got {sigma_s_px}")
    h = np.nan_to_num(h, nan=np.nanmin(h) if np.any(np.isfinite(h)) else 0.0)
    d2 = ((x - x_bar_px) / sigma_s_px) ** 2
    window = np.exp(-0.5 * (d2 - d2.min()))  # eq. (21), Gaussian up to a constant factor
    h_mod = (h - h.min()) * window  # eq. (21)
    total = h_mod.sum()
    if not total > 0:
        return np.full(h.size, 1.0 / h.size)
    return h_mod / total  # eq. (20)


def _check_axis(h_values, axis_positions_px) -> tuple[np.ndarray, np.ndarray]:
    h = np.asarray(h_values, dtype=float)
    x = np.asarray(axis_positions_px, dtype=float)
    if h.ndim != 1 or h.size < 2:
        raise ValueError(f"h_values must be a 1-D array of at least 2 values, got {h.shape}")
    if x.shape != h.shape:
        raise ValueError(f"axis_positions_px has shape {x.shape} but h_values has shape {h.shape}")
    if not np.all(np.diff(x) > 0):
        raise ValueError("axis_positions_px must be strictly increasing")
    return h, x


@dataclass(frozen=True)
class MathiassenPFParams:
    """Parameters of Mathiassen 2017's tip particle filter (section III-B); pixels and
    seconds (0.10 mm/px in the paper).

    The defaults are the PF without velocity measurements; ``pf_v()`` gives PF_v.
    Standard deviations written in the paper as (dT / sqrt 2) * rate are stored as the rate,
    in px/s, and multiplied by dT / sqrt 2 in the properties.
    """

    n_particles: int = 200
    dt_s: float = 0.05  # 20 frames/s, the frame-grabber rate of section III
    init_position_rate_px_s: float = 50.0  # initial position std = (dT / sqrt 2) 50 px
    init_velocity_std_px_s: float = 50.0  # 5 px/s with velocity measurements
    sigma_s_px: float = 150.0  # eq. (21); 75 px with velocity measurements
    process_position_rate_px_s: float = 100.0  # process position std = (dT / sqrt 2) 100 px
    process_velocity_std_px_s: float = 100.0  # 5 px/s with velocity measurements
    velocity_variance_px2_s2: float = 1.0  # R_v of eq. (23), "1 px^2" in the paper
    # Not given in the paper: the generic PF [23] resamples when N_eff < threshold * N.
    resample_threshold: float = 0.5
    # x_bar of eq. (21): "prediction" = the predicted (prior) mean tip position, which is how
    # the text defines it ("the current estimate of the tip position"); "measurement_peak" =
    # the argmax of h, the literal second argument y_k of eq. (22).
    window_centre: str = "prediction"

    def __post_init__(self) -> None:
        if self.n_particles < 1:
            raise ValueError("n_particles must be at least 1")
        if not self.dt_s > 0:
            raise ValueError("dt_s must be positive")
        if self.window_centre not in ("prediction", "measurement_peak"):
            raise ValueError(
                "window_centre must be 'prediction' or 'measurement_peak', "
                f"got {self.window_centre!r}"
            )

    @classmethod
    def pf(cls, **overrides) -> MathiassenPFParams:
        """Section III-B, PF (no robot velocity measurements)."""
        return cls(**overrides)

    @classmethod
    def pf_v(cls, **overrides) -> MathiassenPFParams:
        """Section III-B, PF_v (robot velocity measurements available)."""
        values = dict(init_velocity_std_px_s=5.0, sigma_s_px=75.0, process_velocity_std_px_s=5.0)
        values.update(overrides)
        return cls(**values)

    @property
    def init_position_std_px(self) -> float:
        return self.dt_s / np.sqrt(2.0) * self.init_position_rate_px_s

    @property
    def process_position_std_px(self) -> float:
        return self.dt_s / np.sqrt(2.0) * self.process_position_rate_px_s


@dataclass(frozen=True)
class TipEstimate:
    """Posterior estimate after one ``step``: false-valued when the measurement was not used
    (the estimate is then the prediction)."""

    position_px: float
    velocity_px_s: float
    covariance: np.ndarray = field(repr=False)
    updated: bool = True
    reason: str = ""

    def __bool__(self) -> bool:
        return self.updated


class MathiassenTipParticleFilter:
    """Mathiassen 2017, Algorithm 5 (lines 4-11): particle filter on the tip position.

    State x = [x (px along the needle axis), v (px/s)]; system model eq. (11) with independent
    Gaussian process noise on position and velocity; measurement model eqs. (20)-(23).

    Parameters
    ----------
    initial_position_px : float
        Where the tip is expected to appear (px along the axis).
    initial_velocity_px_s : float
        Mean of the initial velocity particles (px/s); for PF_v the robot's velocity.
    params : MathiassenPFParams
    rng : Generator, int or None
    """

    def __init__(
        self,
        initial_position_px: float,
        initial_velocity_px_s: float = 0.0,
        params: MathiassenPFParams | None = None,
        rng: RngLike = None,
    ) -> None:
        self.params = MathiassenPFParams() if params is None else params
        p = self.params
        rng = np.random.default_rng(rng)
        mean = np.array([initial_position_px, initial_velocity_px_s], dtype=float)
        std = np.array([p.init_position_std_px, p.init_velocity_std_px_s])
        particles = mean + std * rng.standard_normal((p.n_particles, 2))
        self.filter = ParticleFilter(
            particles,
            resampler=systematic_resample,  # section II-D: systematic resampling
            resample_threshold=p.resample_threshold,
            rng=rng,
        )
        dt = p.dt_s
        self.F = np.array([[1.0, dt], [0.0, 1.0]])  # eq. (11)
        self.process_std = np.array([p.process_position_std_px, p.process_velocity_std_px_s])

    def _transition(self, particles: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        noise = self.process_std * rng.standard_normal(particles.shape)  # w_k of eq. (11)
        return particles @ self.F.T + noise  # eq. (11)

    def step(
        self,
        h_values_along_axis,
        axis_positions_px,
        velocity_measurement: float | None = None,
        rng: RngLike = None,
    ) -> TipEstimate:
        """One frame: predict with eq. (11), weight with eq. (22) or (23), resample when
        needed, and return the weighted mean (Algorithm 5, line 11: p_n <- x_k).

        ``velocity_measurement`` is the robot's tip velocity along the axis in px/s (z-dot of
        eq. (23)); None for the image-only PF.
        """
        h, x_axis = _check_axis(h_values_along_axis, axis_positions_px)
        p = self.params
        pf = self.filter
        pf.predict(self._transition, rng)  # Algorithm 5: prior as importance density
        if p.window_centre == "prediction":
            x_bar = float(pf.mean[0])
        else:
            x_bar = float(x_axis[np.nanargmax(h)]) if np.any(np.isfinite(h)) else pf.mean[0]
        density = h_pdf(h, x_axis, x_bar, p.sigma_s_px)  # eqs. (20)-(21)

        def log_likelihood(particles: np.ndarray) -> np.ndarray:
            # eq. (22): linear interpolation of h_pdf at each position particle; zero off axis
            lik = np.interp(particles[:, 0], x_axis, density, left=0.0, right=0.0)
            with np.errstate(divide="ignore"):
                out = np.log(lik)
            if velocity_measurement is not None:
                # eq. (23): Gaussian velocity likelihood (its constant factor cancels)
                r_v = p.velocity_variance_px2_s2
                out = out - 0.5 * (particles[:, 1] - velocity_measurement) ** 2 / r_v
            return out

        outcome = pf.update(log_likelihood, rng, log=True)
        mean, cov = pf.estimate()
        return TipEstimate(
            position_px=float(mean[0]),
            velocity_px_s=float(mean[1]),
            covariance=cov,
            updated=outcome.ok,
            reason=outcome.reason,
        )
