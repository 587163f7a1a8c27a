"""Carriere 2016: the non-holonomic bicycle model of a bevel-tip needle and the particle
filter over its parameters (R, theta_0).

Units: lengths in mm. Angles in radians in every function, except the particle filter, which
keeps theta_0 in degrees as the paper's prior theta_0 ~ N(0, 5) is written (5 radians would
be absurd for a needle's entry angle; 5 degrees is plausible). R is signed: R > 0 bends the
needle towards +u (the heading theta grows, beta > 0 in eq. (2)), R < 0 towards -u.

Conventions this module fixes where the paper is loose:

* Heading. theta is the tip angle from the insertion axis (v, equivalently z) towards +u, as
  in eq. (2): dv = cos(theta) ds, du = sin(theta) ds. The centre of rotation of eq. (4) is
  then (u_c, v_c) = (u_turn + R cos theta, v_turn - R sin theta), i.e. the signs (+, -) of
  the "+-" in eq. (4): the centre lies on the normal of the heading. With this choice eq. (7)'s
  atan(v_c / u_c) equals -theta_0.
* Plane angle. Eq. (5) is printed as x = cos(phi) u, y = sin(phi) v, z = v; y = sin(phi) v is
  a typo for sin(phi) u (otherwise a straight needle, u = 0, would drift in y with depth,
  and the map would not place the (u, v) plane at angle phi about z). We use x = cos(phi) u,
  y = sin(phi) u, z = v, so phi = atan2(y, x) of the deflection. The printed eq. (2) has
  sin(phi) in the x row and cos(phi) in the y row, which measures phi from the y axis and
  disagrees with eq. (5); ``bicycle_step`` uses eq. (5)'s convention (x row sin(theta)
  cos(phi), y row sin(theta) sin(phi)) so that the two agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._particle import RngLike, UpdateOutcome

__all__ = [
    "bicycle_step",
    "curvature_radius",
    "heading_increment",
    "bicycle_path",
    "fit_plane_angle_pca",
    "xyz_to_uv",
    "uv_to_xyz",
    "CarriereParams",
    "CarriereParticleFilter",
    "tip_error",
    "shape_error",
]


def bicycle_step(state, alpha, beta) -> np.ndarray:
    """One step of the 3-D non-holonomic bicycle model, Carriere 2016, eq. (2).

    X_{k+1} = X_k + B(X_k) [alpha, beta]^T with X = [x, y, z, theta, phi]:
    x += alpha sin(theta) cos(phi), y += alpha sin(theta) sin(phi), z += alpha cos(theta),
    theta += beta, phi unchanged (see the module docstring for the x/y rows).

    Parameters
    ----------
    state : (..., 5) array
        Any number of states, mm and radians.
    alpha : float or array broadcastable to state[..., 0]
        Insertion distance along the needle per step (mm).
    beta : float or array broadcastable to state[..., 0]
        Change of the tip angle theta per step (rad); for a bicycle of wheelbase l and
        steering angle b moving alpha, beta = alpha / R = alpha sin(b) / l
        (``heading_increment``).
    """
    x = np.asarray(state, dtype=float)
    if x.shape[-1:] != (5,):
        raise ValueError(f"state must have shape (..., 5), got {x.shape}")
    alpha = np.asarray(alpha, dtype=float)
    beta = np.asarray(beta, dtype=float)
    theta, phi = x[..., 3], x[..., 4]
    out = np.array(
        np.broadcast_to(x, np.broadcast_shapes(x.shape, alpha.shape + (1,), beta.shape + (1,)))
    )
    s = np.sin(theta)
    out[..., 0] += alpha * s * np.cos(phi)  # eq. (2), row 1 (phi as in eq. (5))
    out[..., 1] += alpha * s * np.sin(phi)  # eq. (2), row 2 (phi as in eq. (5))
    out[..., 2] += alpha * np.cos(theta)  # eq. (2), row 3
    out[..., 3] += beta  # eq. (2), row 4
    return out  # eq. (2), row 5: phi constant


def curvature_radius(wheelbase_mm, steering_angle_rad):
    """R = l / sin(beta), Carriere 2016, section III (beta the front-wheel angle)."""
    return np.asarray(wheelbase_mm, dtype=float) / np.sin(steering_angle_rad)


def heading_increment(alpha_mm, radius_mm):
    """Change of theta over an arc of length alpha on a circle of signed radius R: alpha / R.

    This is the beta input of ``bicycle_step`` that makes eq. (2) follow the circle of
    radius R = l / sin(b).
    """
    return np.asarray(alpha_mm, dtype=float) / np.asarray(radius_mm, dtype=float)


def _arc(u_c, v_c, r, v):
    """Eq. (3) on the branch through the needle: u = u_c - sign(R) sqrt(R^2 - (v - v_c)^2)
    (the point lies at -R (cos theta, -sin theta) from the centre); NaN off the circle (the
    caller silences the square root's warning there)."""
    return u_c - np.sign(r) * np.sqrt(r**2 - (v - v_c) ** 2)


def bicycle_path(v, R, theta0, turn_depths=()) -> np.ndarray:
    """Closed-form needle path u(v) in the (u, v) plane, Carriere 2016, eqs. (3)-(4).

    The tip starts at (0, 0) with heading theta0 and follows circular arcs of radius |R|.
    Segment i starts at v_turn(i) (v_turn(0) = 0); at each turn depth the bevel rotates by
    180 degrees, the sign of R flips, and the new centre of rotation (eq. (4)) is the old one
    reflected through the turn point (u_turn, v_turn), so u and du/dv are continuous and the
    curvature is mirrored. Within a segment, eq. (3):
    u = u_c - sign(R) sqrt(R^2 - (v - v_c)^2).

    Parameters
    ----------
    v : (P,) array
        Depths along the insertion axis (mm). Depths before 0 follow the first arc.
    R : float or array
        Signed radius of curvature (mm) of the first segment.
    theta0 : float or array broadcastable with R
        Initial heading (rad), from the v axis towards +u.
    turn_depths : sequence of float
        Depths (mm) of the 180-degree bevel rotations.

    Returns
    -------
    u : array of shape broadcast(R, theta0).shape + (P,)
        Deflection (mm). NaN where the path has no solution (R = 0, or the arc would turn
        past 90 degrees from the insertion axis before reaching v).
    """
    v = np.asarray(v, dtype=float)
    if v.ndim != 1:
        raise ValueError(f"v must be a 1-D array of depths, got shape {v.shape}")
    R, theta0 = np.asarray(R, dtype=float), np.asarray(theta0, dtype=float)
    if R.shape != theta0.shape:
        R, theta0 = np.broadcast_arrays(R, theta0)
    r = np.where(R == 0, np.nan, R)[..., None]
    th = theta0[..., None]
    turns = np.sort(np.asarray(turn_depths, dtype=float).ravel())
    if turns.size and turns[0] <= 0:
        raise ValueError("turn_depths must be positive (the path starts at v = 0)")
    u_c = r * np.cos(th)  # eq. (4), u_turn(0) = 0
    v_c = -r * np.sin(th)  # eq. (4), v_turn(0) = 0
    with np.errstate(invalid="ignore"):
        if not turns.size:  # one arc: eq. (3) at every depth
            return _arc(u_c, v_c, r, v)
        u = np.empty(r.shape[:-1] + v.shape)
        starts = np.concatenate([[-np.inf], turns])
        ends = np.concatenate([turns, [np.inf]])
        for i, (start, end) in enumerate(zip(starts, ends, strict=True)):
            in_segment = (v >= start) & (v < end)
            u[..., in_segment] = _arc(u_c, v_c, r, v[in_segment])  # eq. (3)
            if i < turns.size:
                v_turn = end
                u_turn = _arc(u_c, v_c, r, v_turn)  # eq. (3) at the turn
                # eq. (4) for segment i + 1 with R -> -R and theta_turn from segment i
                # (sin = (v_turn - v_c) / R, cos = (u_c - u_turn) / R):
                # u_c(i+1) = u_turn - R cos(theta_turn) = 2 u_turn - u_c(i),
                # v_c(i+1) = v_turn + R sin(theta_turn) = 2 v_turn - v_c(i).
                u_c, v_c, r = 2 * u_turn - u_c, 2 * v_turn - v_c, -r
    return u


def fit_plane_angle_pca(points_xyz) -> float:
    """Angle phi (rad, in (-pi/2, pi/2]) of the needle's deflection plane about z by
    principal component analysis (Carriere 2016, section IV): the first principal axis of the
    centred (x, y) coordinates is (cos phi, sin phi), eq. (5).

    The sign of the axis is not identifiable (phi and phi + pi describe the same plane with u
    negated). A needle with no (x, y) spread has no plane; 0.0 is returned.
    """
    p = np.asarray(points_xyz, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
        raise ValueError(f"points_xyz must be an (N, 3) array with N >= 2, got {p.shape}")
    xy = p[:, :2] - p[:, :2].mean(axis=0)
    _, s, vt = np.linalg.svd(xy, full_matrices=False)
    if s[0] <= 0:
        return 0.0
    phi = float(np.arctan2(vt[0, 1], vt[0, 0]))
    if phi <= -np.pi / 2:
        phi += np.pi
    elif phi > np.pi / 2:
        phi -= np.pi
    return phi


def xyz_to_uv(points_xyz, phi: float, origin_xyz=None) -> np.ndarray:
    """(x, y, z) -> (u, v) by inverting eq. (5) (with y = sin(phi) u, see module docstring):
    u = (x - x0) cos phi + (y - y0) sin phi, v = z - z0.

    ``origin_xyz`` defaults to the first point, the origin of the (u, v) plane in Carriere
    2016, section IV (u_0 = v_0 = 0). The component normal to the plane is dropped.
    Returns an (N, 2) array of (u, v) in mm.
    """
    p = np.asarray(points_xyz, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 1:
        raise ValueError(f"points_xyz must be an (N, 3) array, got shape {p.shape}")
    o = p[0] if origin_xyz is None else np.asarray(origin_xyz, dtype=float)
    d = p - o
    u = d[:, 0] * np.cos(phi) + d[:, 1] * np.sin(phi)
    return np.stack([u, d[:, 2]], axis=1)


def uv_to_xyz(points_uv, phi: float, origin_xyz=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(u, v) -> (x, y, z), Carriere 2016, eq. (5) with the typo fixed:
    x = x0 + cos(phi) u, y = y0 + sin(phi) u, z = z0 + v. Returns (N, 3), mm."""
    q = np.asarray(points_uv, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2:
        raise ValueError(f"points_uv must be an (N, 2) array, got shape {q.shape}")
    u, v = q[:, 0], q[:, 1]
    xyz = np.stack([np.cos(phi) * u, np.sin(phi) * u, v], axis=1)  # eq. (5)
    return xyz + np.asarray(origin_xyz, dtype=float)


@dataclass(frozen=True)
class CarriereParams:
    """Particle filter of Carriere 2016, section IV; mm and degrees.

    ``gain`` is gamma of step 7, which the paper does not give. Each update pulls the
    particles a fraction gamma of the way to the mean of the best-fitting ones, so the cloud
    shrinks about (1 - gamma) per update; with one update per 0.5 mm of insertion (the
    paper's experimental image spacing) the 140 updates from 10 to 80 mm shrink it by
    (1 - 0.02)^140 = 0.06, so the particles stay spread until the curvature becomes
    observable. A gain of 0.5 would collapse the cloud within ten updates, at 15 mm of
    insertion, where a 1500 mm radius deflects the needle by 0.07 mm.
    """

    n_particles: int = 500  # n
    n_points: int = 5  # p
    n_replaced: int = 3  # c
    mu_radius_mm: float = 1500.0  # R ~ N(1500, 600)
    sigma_radius_mm: float = 600.0
    mu_theta0_deg: float = 0.0  # theta_0 ~ N(0, 5), degrees
    sigma_theta0_deg: float = 5.0
    gain: float = 0.02  # gamma, step 7
    warmup_depth_mm: float = 10.0  # no update before the first 10 mm (k_10mm)
    rotation_depth_mm: float = 80.0  # D: the filter stops at the rotation depth

    def __post_init__(self) -> None:
        if self.n_particles < 1 or self.n_points < 1:
            raise ValueError("n_particles and n_points must be at least 1")
        if not 0 <= self.n_replaced <= self.n_particles:
            raise ValueError("n_replaced must lie in [0, n_particles]")
        if not 0.0 <= self.gain <= 1.0:
            raise ValueError(f"gain must lie in [0, 1], got {self.gain}")
        if self.sigma_radius_mm < 0 or self.sigma_theta0_deg < 0:
            raise ValueError("standard deviations must be non-negative")


class CarriereParticleFilter:
    """Carriere 2016, section IV, steps 1-10: particles over (R [mm], theta_0 [deg]).

    Feed the in-plane observations (v, u) of the needle tip one frame at a time with
    ``update``; map (x, y, z) with ``fit_plane_angle_pca`` and ``xyz_to_uv`` first. The first
    observation defines the origin only if it is (0, 0): the model's path starts there.

    Interpretations of the paper's steps (it does not say more):

    * Step 2/10: the p depths are v_max j / p, j = 1..p (equidistant, spanning the observed
      depths); each picks the observed point nearest in depth. Points at v <= 0 are not used:
      every particle predicts u = 0 at the origin, so its argmin would be arbitrary.
    * Step 7: the p best particles (step 5) are kept and all other particles are pulled.
    * Step 9: the c particles removed are those with the largest summed L1 distance.
    * Step 10: observations deeper than D are ignored; the observation at D is the last used.

    Known behaviour (seeded synthetic needles, 0.5 mm spacing, noise 0.2 mm, D = 80 mm): the
    per-point argmin of steps 4-5 is dominated by theta_0, whose effect u ~ theta_0 v is much
    larger than the curvature's u ~ v^2 / 2R over the observed depths, so mu_R moves little
    from its prior mean and mu_theta0 absorbs the difference. With R = 1500 mm (the prior
    mean) theta_0 comes out within about 0.1 degree and the tip at 140 mm (rotated at D)
    within about 0.3 mm; with R = 1000 mm, mu_R stays near 1500 mm, theta_0 is off by about
    0.4 degree and the tip by about 1 mm.
    """

    def __init__(self, params: CarriereParams | None = None, rng: RngLike = None) -> None:
        self.params = CarriereParams() if params is None else params
        p = self.params
        self.rng = np.random.default_rng(rng)
        # step 1: R(n) ~ N(mu_R, sigma_R), theta_0(n) ~ N(mu_theta0, sigma_theta0)
        self.mu = np.array([p.mu_radius_mm, p.mu_theta0_deg], dtype=float)
        self.sigma = np.array([p.sigma_radius_mm, p.sigma_theta0_deg], dtype=float)
        self.particles = self.mu + self.sigma * self.rng.standard_normal((p.n_particles, 2))
        self._v: list[float] = []
        self._u: list[float] = []
        self.n_updates = 0
        self._stopped = False

    @property
    def radius_mm(self) -> float:
        """mu_R, the mean radius of the particles (step 8)."""
        return float(self.mu[0])

    @property
    def theta0_deg(self) -> float:
        """mu_theta0, the mean initial angle of the particles in degrees (step 8)."""
        return float(self.mu[1])

    @property
    def stopped(self) -> bool:
        """True once an observation at or past the rotation depth D has arrived (step 10)."""
        return self._stopped

    def _select_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Steps 2 and 10: p points equidistant in depth from the observed set {k_0 : k}.

        Targets v_max j / p, j = 1..p; each takes the observation nearest in depth among
        those deeper than the origin (shallower on ties)."""
        v = np.asarray(self._v)
        u = np.asarray(self._u)
        deeper = v > 0
        order = np.argsort(v[deeper], kind="stable")  # argmin then prefers the shallower
        v, u = v[deeper][order], u[deeper][order]
        targets = v[-1] * np.arange(1, self.params.n_points + 1) / self.params.n_points
        nearest = np.argmin(np.abs(v[None, :] - targets[:, None]), axis=1)  # (p,)
        return v[nearest], u[nearest]

    def update(self, v_mm: float, u_mm: float) -> UpdateOutcome:
        """Add the observation (v, u) of frame k and run steps 3-9 once.

        Returns a false outcome, with the reason, while the needle is shallower than the
        warm-up depth (10 mm) or after the filter has stopped at the rotation depth D.
        """
        p = self.params
        if self._stopped:
            return UpdateOutcome(False, "stopped at the rotation depth D")
        if not (np.isfinite(v_mm) and np.isfinite(u_mm)):
            return UpdateOutcome(False, "observation is not finite")
        if v_mm > p.rotation_depth_mm:
            self._stopped = True  # step 10: the needle has passed D, terminate
            return UpdateOutcome(False, "observation deeper than the rotation depth D")
        self._v.append(float(v_mm))
        self._u.append(float(u_mm))
        self._stopped = v_mm >= p.rotation_depth_mm  # step 10: k = k_D is the last update
        if max(self._v) < p.warmup_depth_mm:
            return UpdateOutcome(
                False, f"waiting for the first {p.warmup_depth_mm:g} mm of insertion"
            )
        if not any(vk > 0 for vk in self._v):
            return UpdateOutcome(False, "no observation deeper than the origin")

        v_sel, u_sel = self._select_points()  # step 2 / 10
        R, theta0_deg = self.particles[:, 0], self.particles[:, 1]
        u_hat = bicycle_path(v_sel, R, np.deg2rad(theta0_deg))  # step 3: (n, p)
        l1 = np.abs(u_sel - u_hat)  # step 4: L1 distance, (n, p)
        l1 = np.where(np.isnan(l1), np.inf, l1)
        best = np.argmin(l1, axis=0)  # step 5: best particle per point, (p,)
        target = self.particles[best].mean(axis=0)  # step 6: mean R(p), theta_0(p)
        pulled = self.particles - p.gain * (self.particles - target)  # step 7
        keep = np.zeros(p.n_particles, dtype=bool)
        keep[best] = True
        self.particles = np.where(keep[:, None], self.particles, pulled)
        self.mu = self.particles.mean(axis=0)  # step 8
        self.sigma = self.particles.std(axis=0)  # step 8
        if p.n_replaced:
            # step 9: replace the c worst-fitting particles by draws from N(mu, sigma)
            worst = np.argsort(l1.sum(axis=1), kind="stable")[-p.n_replaced :]
            self.particles[worst] = self.mu + self.sigma * self.rng.standard_normal(
                (p.n_replaced, 2)
            )
        self.n_updates += 1
        return UpdateOutcome(True)

    def predict_shape(self, v_values, turn_depths=()) -> np.ndarray:
        """u(v) of the bicycle path with the mean parameters mu_R and mu_theta0 (step 10),
        eqs. (3)-(4). Pass ``turn_depths=(D,)`` to predict the needle rotated at D."""
        return bicycle_path(v_values, self.radius_mm, np.deg2rad(self.theta0_deg), turn_depths)


def tip_error(u, u_hat):
    """Carriere 2016, section V: TipError = |u - u_hat| (mm), the measured against the
    predicted tip deflection at the final depth; elementwise for arrays."""
    err = np.abs(np.asarray(u, dtype=float) - np.asarray(u_hat, dtype=float))
    return float(err) if err.ndim == 0 else err


def shape_error(v, u, u_hat) -> float:
    """Carriere 2016, eq. (8): ShapeError = integral |u - u_hat| dv (mm^2), by the
    trapezoidal rule over the sampled depths v."""
    v = np.asarray(v, dtype=float)
    u = np.asarray(u, dtype=float)
    u_hat = np.asarray(u_hat, dtype=float)
    if v.ndim != 1 or u.shape != v.shape or u_hat.shape != v.shape:
        raise ValueError(
            f"v, u and u_hat must be 1-D arrays of one length, got {v.shape}, {u.shape}, "
            f"{u_hat.shape}"
        )
    f = np.abs(u - u_hat)
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(v)))  # eq. (8), trapezoidal rule
