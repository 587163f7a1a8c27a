"""synth: a fast Field-II-style ultrasound simulator of needle insertions.

Read it as world -> probe -> scanner -> sequence:

- world (:mod:`synth._world`): tissue scatterers, the scattering map, the needle path;
- probe (:mod:`synth._probe`): linear plane, Zhao's sector volume, a matrix probe;
- scanner (:mod:`synth._scanner`, :mod:`synth._imaging`): the convolution model, the needle
  echo, log compression;
- sequences (:mod:`synth._scenarios`, :mod:`synth._sequence`): seeded scenarios of the five
  papers and the ``.npz`` sequence file.
"""

from ._geometry import (
    Grid,
    apply_transform,
    distance_to_polyline,
    invert_rigid,
    rigid_transform,
    rotation_matrix,
)
from ._preview import preview_image, save_preview
from ._probe import MatrixProbe, PlaneProbe, SectorProbe
from ._progress import Progress
from ._render import Trajectory, contrast_ratio, render_sequence, tube_indices
from ._scanner import ImagingParams, Scanner, display_mask, log_compress, speckle_log_mean_db
from ._scenarios import (
    MAX_FRAME_PIXELS,
    SCENARIOS,
    describe,
    generate,
    random_scattering_map,
    scenario_params,
)
from ._sequence import (
    MODALITIES,
    Sequence,
    SequenceFileError,
    load_sequence,
    save_sequence,
    validate_sequence,
)
from ._speckle import (
    RAYLEIGH_LOG_STD_DB,
    RAYLEIGH_SNR,
    envelope_snr,
    log_std_db,
    speckle_fwhm,
    speckle_log_std_db,
)
from ._world import (
    GAUGE_OUTER_DIAMETER_MM,
    NeedlePath,
    NeedleSpec,
    ScatteringMap,
    SpecularLine,
    Tissue,
    World,
    needle_radius_mm,
)

__all__ = [
    "GAUGE_OUTER_DIAMETER_MM", "Grid", "ImagingParams", "MODALITIES", "MatrixProbe",
    "NeedlePath", "NeedleSpec", "PlaneProbe", "Progress", "RAYLEIGH_LOG_STD_DB", "RAYLEIGH_SNR",
    "SCENARIOS", "Scanner", "ScatteringMap", "SectorProbe", "Sequence", "SequenceFileError",
    "SpecularLine",
    "Tissue", "Trajectory", "World", "apply_transform", "contrast_ratio", "describe",
    "display_mask", "distance_to_polyline", "envelope_snr", "speckle_log_mean_db",
    "speckle_log_std_db", "generate", "invert_rigid", "load_sequence",
    "log_compress", "log_std_db",
    "needle_radius_mm", "preview_image", "random_scattering_map", "render_sequence",
    "rigid_transform", "rotation_matrix", "save_preview", "save_sequence", "scenario_params",
    "speckle_fwhm", "tube_indices", "validate_sequence",
           "MAX_FRAME_PIXELS"]
