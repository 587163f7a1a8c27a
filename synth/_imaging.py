"""Scanner settings and what the display does to an envelope: log compression, grey map
and the 2D display mask."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import digamma

__all__ = ["ImagingParams", "log_compress", "display_mask", "speckle_log_mean_db"]

_FWHM = 2.0 * np.sqrt(2.0 * np.log(2.0))  # FWHM of a Gaussian = 2.3548 sigma


_MAX_DB = 200.0  # the largest gain or level in dB a parameter may give

@dataclass(frozen=True)
class ImagingParams:
    """Scanner settings (units in the names). Defaults: a 5 MHz linear array."""

    center_frequency_mhz: float = 5.0
    fractional_bandwidth: float = 0.6  # -6 dB, of the pulse-echo spectrum
    f_number: float = 2.0  # receive (dynamic focusing): constant lateral width lambda * F#
    tx_focus_mm: float = 25.0
    tx_f_number: float = 3.0
    elevation_focus_mm: float = 20.0
    elevation_f_number: float = 5.0
    attenuation_db_cm_mhz: float = 0.5
    tgc_compensation: float = 1.0  # fraction of the attenuation that TGC gives back
    noise_db: float = -45.0  # electronic noise RMS re unit-echogenicity speckle RMS
    dynamic_range_db: float = 70.0
    tissue_gray: float = 70.0  # mean gray level of unit-echogenicity speckle
    speed_of_sound_m_s: float = 1540.0
    scatterers_per_cell: float = 40.0  # per resolution cell (FWHM box), at the smallest cell
    max_density_per_mm3: float = 2000.0
    # spatial compounding: independent speckle realisations (looks) of the same tissue,
    # averaged in intensity; the needle's coherent echo is the same in every look
    compound_looks: int = 1
    # TGC sliders: gains (dB) at evenly spaced depths from the first to the last row,
    # interpolated between them; applied to echo and noise alike (empty: none)
    tgc_curve_db: tuple = ()
    # grey map after log compression: g -> 255 (min(g, gray_white) / gray_white)^gray_gamma
    # + gray_offset (the identity with the defaults); gray_white < 255 saturates bright echoes
    gray_gamma: float = 1.0
    gray_offset: float = 0.0
    gray_white: float = 255.0
    # 2D frames: black screen-capture margins (top, bottom, left, right; mm of the frame's
    # grid: the grid is unchanged, those pixels are 0) and a sector (fan) mask with its apex
    # sector_apex_mm above the top row's centre (0: no mask); pixels outside are 0
    margin_mm: tuple = (0.0, 0.0, 0.0, 0.0)
    sector_half_angle_deg: float = 0.0
    sector_apex_mm: float = 0.0
    # reverberation between the probe face and the skin: bright bands every
    # face_reverb_spacing_mm below the face, the first at face_reverb_gain (re unit speckle
    # RMS), each face_reverb_decay times the one before (gain 0: none)
    face_reverb_gain: float = 0.0
    face_reverb_spacing_mm: float = 1.5
    face_reverb_decay: float = 0.5

    def __post_init__(self) -> None:
        positive = ["center_frequency_mhz", "fractional_bandwidth", "f_number", "tx_focus_mm",
                    "tx_f_number", "elevation_focus_mm", "elevation_f_number",
                    "dynamic_range_db", "speed_of_sound_m_s", "scatterers_per_cell",
                    "gray_gamma", "gray_white", "face_reverb_spacing_mm"]
        for name in positive:
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"ImagingParams.{name} must be positive, got {v}")
        if self.attenuation_db_cm_mhz < 0:
            raise ValueError("ImagingParams.attenuation_db_cm_mhz must be >= 0")
        # gains in dB become amplitudes 10^(dB/20): beyond +-200 dB (a factor of 10^10) a
        # level means nothing on an 8-bit image, and beyond some 6,000 dB it overflows
        levels = {"noise_db": [self.noise_db], "tgc_curve_db": list(self.tgc_curve_db)}
        for name, values in levels.items():
            if not all(np.isfinite(v) and abs(v) <= _MAX_DB for v in values):
                raise ValueError(f"ImagingParams.{name} must lie within +-{_MAX_DB:g} dB, got "
                                 f"{values if len(values) != 1 else values[0]}")
        if int(self.compound_looks) != self.compound_looks or self.compound_looks < 1:
            raise ValueError("ImagingParams.compound_looks must be a whole number >= 1, got "
                             f"{self.compound_looks}")
        object.__setattr__(self, "compound_looks", int(self.compound_looks))
        object.__setattr__(self, "tgc_curve_db", tuple(float(v) for v in self.tgc_curve_db))
        m = tuple(float(v) for v in self.margin_mm)
        if len(m) != 4 or min(m) < 0:
            raise ValueError("ImagingParams.margin_mm must be 4 values >= 0 (top, bottom, "
                             f"left, right), got {self.margin_mm}")
        object.__setattr__(self, "margin_mm", m)
        if not 0.0 <= self.sector_half_angle_deg < 90.0 or self.sector_apex_mm < 0:
            raise ValueError("ImagingParams.sector_half_angle_deg must be in [0, 90) and "
                             "sector_apex_mm >= 0")
        if self.gray_white > 255 or self.face_reverb_gain < 0 or \
                not 0.0 <= self.face_reverb_decay < 1.0:
            raise ValueError("ImagingParams: gray_white must be <= 255, face_reverb_gain >= 0 "
                             "and face_reverb_decay in [0, 1)")

    @classmethod
    def from_dict(cls, d: dict) -> ImagingParams:
        """The parameters a sequence's ``meta["imaging"]`` records (lists read as tuples)."""
        names = set(cls.__dataclass_fields__)
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()
                      if k in names})

    @property
    def has_gray_map(self) -> bool:
        return (self.gray_gamma, self.gray_offset, self.gray_white) != (1.0, 0.0, 255.0)

    @property
    def wavelength_mm(self) -> float:
        return self.speed_of_sound_m_s * 1e-3 / self.center_frequency_mhz

    @property
    def k0_per_mm(self) -> float:
        return 2.0 * np.pi / self.wavelength_mm

    @property
    def sigma_axial_mm(self) -> float:
        """Gaussian pulse: spectral FWHM = B f0, envelope sigma_t = 1 / (2 pi sigma_f), two-way."""
        sigma_f = self.fractional_bandwidth * self.center_frequency_mhz / _FWHM  # MHz
        sigma_t_us = 1.0 / (2.0 * np.pi * sigma_f)
        return self.speed_of_sound_m_s * 1e-3 * sigma_t_us / 2.0

    def _beam_fwhm(self, z: np.ndarray, f_number: float, focus: float) -> np.ndarray:
        # Gaussian beam, one way: FWHM lambda F# at the focus, growing with the distance to it
        # over a depth of field 7.08 lambda F#^2 (the usual -6 dB depth of field).
        lam = self.wavelength_mm
        z_r = 0.5 * 7.08 * lam * f_number**2
        return lam * f_number * np.sqrt(1.0 + ((np.asarray(z, float) - focus) / z_r) ** 2)

    def sigma_lateral_mm(self, z: np.ndarray) -> np.ndarray:
        """Two-way lateral width: product of transmit (fixed focus) and receive (dynamic) beams."""
        s_tx = self._beam_fwhm(z, self.tx_f_number, self.tx_focus_mm) / _FWHM
        s_rx = self.wavelength_mm * self.f_number / _FWHM
        return 1.0 / np.sqrt(1.0 / s_tx**2 + 1.0 / s_rx**2)

    def sigma_elevation_mm(self, z: np.ndarray) -> np.ndarray:
        """Two-way elevation width: the same fixed lens on transmit and receive."""
        return self._beam_fwhm(z, self.elevation_f_number, self.elevation_focus_mm) / (
            _FWHM * np.sqrt(2.0)
        )

    def psf_fwhm_mm(self, z: float) -> tuple[float, float, float]:
        """(axial, lateral, elevation) FWHM of the pulse-echo PSF amplitude at depth z."""
        return (_FWHM * self.sigma_axial_mm, float(_FWHM * self.sigma_lateral_mm(z)),
                float(_FWHM * self.sigma_elevation_mm(z)))

    def scatterer_density(self, depths_mm: np.ndarray) -> float:
        """Scatterers per mm^3 so the smallest resolution cell holds ``scatterers_per_cell``."""
        z = np.asarray(depths_mm, float)
        cell = (_FWHM**3) * self.sigma_axial_mm * self.sigma_lateral_mm(z) * (
            self.sigma_elevation_mm(z))
        return float(min(self.scatterers_per_cell / cell.min(), self.max_density_per_mm3))

    def two_way_attenuation(self, z_mm: np.ndarray) -> np.ndarray:
        db = self.attenuation_db_cm_mhz * self.center_frequency_mhz * 2.0 * np.asarray(z_mm) / 10
        return 10.0 ** (-db / 20.0)


def speckle_log_mean_db(looks: int = 1) -> float:
    """Mean of 10 log10 of the intensity of fully developed speckle of unit mean intensity,
    averaged over ``looks`` independent looks (a Gamma(looks) intensity):
    10 / ln 10 (psi(looks) - ln looks); -2.507 dB for one look."""
    if looks == 1:
        return -2.507
    return float(10.0 / np.log(10.0) * (digamma(looks) - np.log(looks)))


def log_compress(envelope: np.ndarray, params: ImagingParams) -> np.ndarray:
    """Envelope (unit-echogenicity speckle has RMS 1) -> uint8 over the dynamic range, then
    the grey map.

    The mean of 20 log10 of a Rayleigh envelope of unit RMS is -2.507 dB (of ``looks``
    compounded looks: :func:`speckle_log_mean_db`), so unit speckle lands at ``tissue_gray``
    on average before the grey map.
    """
    db = 20.0 * np.log10(np.maximum(envelope, 1e-12)) - speckle_log_mean_db(
        params.compound_looks)
    gray = params.tissue_gray + db * (255.0 / params.dynamic_range_db)
    if params.has_gray_map:
        g = np.clip(gray, 0.0, params.gray_white) / np.float32(params.gray_white)
        gray = 255.0 * g ** np.float32(params.gray_gamma) + np.float32(params.gray_offset)
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8)


def display_mask(grid, params: ImagingParams) -> np.ndarray | None:
    """Where a 2D frame shows the scan (True) and where it is black (False): the capture
    margins and the sector mask of ``params`` on ``grid`` (depth, lateral); None when there
    are neither (and for 3D grids, which have no display mask)."""
    if grid.ndim != 2 or (not any(params.margin_mm) and params.sector_half_angle_deg == 0):
        return None
    z = np.asarray(grid.axis_coords(0))[:, None]
    x = np.asarray(grid.axis_coords(1))[None, :]
    top, bottom, left, right = params.margin_mm
    keep = ((z >= z[0, 0] + top) & (z <= z[-1, 0] - bottom)
            & (x >= x[0, 0] + left) & (x <= x[0, -1] - right))
    if params.sector_half_angle_deg > 0:
        xc = 0.5 * (x[0, 0] + x[0, -1])
        za = z[0, 0] - params.sector_apex_mm
        ang = np.degrees(np.arctan2(np.abs(x - xc), z - za))
        r = np.hypot(x - xc, z - za)
        keep &= (ang <= params.sector_half_angle_deg) & (r >= params.sector_apex_mm)
    return keep
