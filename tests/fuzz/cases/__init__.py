"""A seeded generator of bad inputs for ``needlenet track`` and ``needlenet synth`` (issue 21).

**Valid inputs first.** :class:`Base` makes, once per run, small valid recordings of each kind
the readers take: ``synth.generate`` sequences (in-plane 5 x 100 x 120 px, axial 5 x 80 x 80,
volume 3 x 32^3: every case then runs in well under a second) written as ``.npz``, PLUS
``.seq.mha`` compressed and not, ``.mhd`` + ``.raw`` / ``.zraw``, float PLUS pixels, NRRD with
the data attached (raw and gzip) and detached, a float NRRD, a PNG folder with and without a
sidecar JSON, an ``.avi`` with and without one, DICOM cine loops (gray with a calibrated
ultrasound region, also without a suffix; colour JPEG; RLE with PixelSpacing), and tiny valid
ONNX models (made with
``onnx.helper``, like ``tests/features/test_model_checks.py``).

**Cases.** :func:`generate_cases` yields :class:`Case` objects: an id, a family, a one-line
description of the mutation, the ``needlenet`` argv (``{d}`` stands for the case's own
directory), the files the case needs (copies of the valid inputs, some mutated) and what may
happen: by default a clean one-line error or a clean run; cases on output paths also name the
outputs that may be written (anything else that changes is damage). Case ``i`` of seed ``s``
draws from ``numpy.random.default_rng([s, i])`` and its family is fixed by ``i``
(:data:`SCHEDULE`, round robin), so the same seed gives the same cases, the first ``n`` cases
of a longer run are the ``n`` cases of a shorter one, and any 51 consecutive cases cover
every family.

**Families** (see :data:`FAMILIES`): bytes flipped or cut in every file kind; npz arrays with
keys removed, wrong dtypes and shapes, NaN / inf, forged array headers and edited meta JSON;
PLUS header fields (DimSize, ElementSpacing, ElementType, CompressedDataSize, HeaderSize,
ElementDataFile, NDims, Offset, Kinds, channels, orientation, timestamps, ImageStatus,
transforms, needlenet's own JSON field); float pixels that are NaN, inf or 1e6; NRRD fields
(type, dimension, sizes, encoding, endian, data file, space directions, spacings, kinds,
origin, skips, frame times); PNG folders and videos (damaged, odd-sized, 16-bit, colour,
empty, bogus sizes in the PNG and JPEG headers) and their sidecar JSON; models (metadata,
ranks, fixed shapes, output shapes and types, NaN / inf outputs, damaged files);
``--param`` with wrong types, huge, negative and non-finite values for the real fields of
the tracker parameter classes (read from the dataclasses, so the suite follows the code);
absurd ``--spacing --fps --crop --angle --tracker --method --seed --igtl`` options; output
paths (existing directories, the input and the files beside it, missing or unwritable
directories, existing files with and without ``--overwrite``, names too long); ``synth``
options; special files (FIFOs, devices, symlinks, folders named like files); bombs (files of
kilobytes whose headers claim, or whose compressed data inflates to, gigabytes); and
DICOM attributes (the pixel module, the transfer syntax, frame times, pixel spacing and the
ultrasound region's calibration) set to bad values or removed, and DICOM bytes flipped or cut;
and controls, valid inputs that must track.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ._base import Base, Case
from ._cli import fam_model, fam_options, fam_output, fam_param, fam_synth
from ._dicom import fam_dicom
from ._npz_plus import fam_npz_arrays, fam_npz_bytes, fam_pixels, fam_plus_bytes, fam_plus_header
from ._nrrd_frames import fam_frames, fam_nrrd_bytes, fam_nrrd_header, fam_video
from ._special import fam_bomb, fam_control, fam_special

__all__ = ["Case", "Base", "FAMILIES", "SCHEDULE", "generate_cases", "make_case"]


FAMILIES = {
    "npz-bytes": fam_npz_bytes, "npz-arrays": fam_npz_arrays, "plus-header": fam_plus_header,
    "plus-bytes": fam_plus_bytes, "pixels": fam_pixels, "nrrd-header": fam_nrrd_header,
    "nrrd-bytes": fam_nrrd_bytes, "frames": fam_frames, "video": fam_video, "model": fam_model,
    "param": fam_param, "options": fam_options, "output": fam_output, "synth": fam_synth,
    "special": fam_special, "control": fam_control, "bomb": fam_bomb, "dicom": fam_dicom,
}
# one round of the schedule: the families weighted by how many distinct fields they touch
SCHEDULE = ("plus-header", "npz-arrays", "param", "output", "model", "options", "nrrd-header",
            "frames", "plus-header", "npz-bytes", "video", "synth", "pixels", "plus-bytes",
            "npz-arrays", "param", "output", "model", "options", "nrrd-bytes", "plus-header",
            "frames", "nrrd-header", "special", "control", "plus-header", "npz-arrays",
            "param", "output", "model", "options", "video", "synth", "pixels", "nrrd-header",
            "frames", "plus-bytes", "npz-bytes", "plus-header", "output", "param", "model",
            "options", "npz-arrays", "nrrd-bytes", "special", "control", "synth", "bomb",
            "dicom", "dicom")


def make_case(seed: int, index: int, base: Base) -> Case:
    """Case ``index`` of ``seed``: its family from :data:`SCHEDULE`, its draws from
    ``default_rng([seed, index])``."""
    family = SCHEDULE[index % len(SCHEDULE)]
    rng = np.random.default_rng([seed, index])
    spec = FAMILIES[family](rng, base)
    spec["family"] = family
    return Case(id=f"{index:05d}-{family}", **spec)


def generate_cases(n: int, seed: int, base: Base, only=None) -> Iterator[Case]:
    """The first ``n`` cases of ``seed`` (or only the indices in ``only``)."""
    for i in (range(n) if only is None else sorted(only)):
        yield make_case(seed, i, base)
