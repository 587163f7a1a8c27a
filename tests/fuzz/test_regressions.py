"""Small files that claim, or inflate to, gigabytes (found by the fuzz suite's ``bomb``
family): each reader refuses them from their headers, before allocating, in well under a
second. The other regressions the suite found are tested beside the code they concern
(``tests/io/test_bad_input.py``, ``tests/features/test_model_checks.py``,
``tests/needlenet/test_cli_io.py``)."""

import resource
import time

import numpy as np
import pytest

from needlenet.io import RecordingError, load_recording

from .cases._base import join_mha, join_nrrd, nrrd_set, set_field, split_mha, split_nrrd
from .cases._npz_plus import _npy_header
from .cases._special import _npz_members, deflate_zeros, zip_bytes


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    import synth
    from needlenet.io import save_plus_sequence

    d = tmp_path_factory.mktemp("bombs")
    seq = synth.generate("inplane", seed=1, frames=3, width_mm=8.0, depth_mm=6.0,
                         start_length_mm=3.0, background="homogeneous")
    npz = synth.save_sequence(seq, d / "s.npz").read_bytes()
    mha = save_plus_sequence(seq, d / "s.seq.mha")[0].read_bytes()
    from .cases._base import _nrrd_2d

    nrrd = _nrrd_2d(seq.images, seq.spacing_mm, seq.timestamps_s)
    return d, npz, mha, nrrd, deflate_zeros(b"", 2560)


def _refused_quickly(path, message):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(RecordingError, match=message):
        load_recording(path)
    assert time.perf_counter() - t0 < 5
    grew_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert grew_mb < 200, f"resident peak grew by {grew_mb:.0f} MB"


def test_npz_whose_zip_directory_and_array_header_agree_on_4_gb(files):
    """numpy allocated the 4.2 GB the forged sizes described before reading 84 bytes."""
    d, npz, *_ = files
    members = [m for m in _npz_members(npz) if m[0] != "images.npy"]
    head = _npy_header((8, 16384, 32000))
    import zlib

    c = zlib.compressobj(6, zlib.DEFLATED, -15)
    comp = c.compress(head + bytes(100)) + c.flush()
    # the CRC of what the stream holds: zipfile checks it when the stream ends, which it
    # does at once here; a wrong one would refuse the file before numpy reads the header
    members.append(("images.npy", comp, 8, zlib.crc32(head + bytes(100)), len(comp),
                    len(head) + 8 * 16384 * 32000))
    (d / "forged.npz").write_bytes(zip_bytes(members))
    _refused_quickly(d / "forged.npz", r"key 'images': its header describes 4194304000 bytes, "
                                       r"more than its \d+ compressed bytes can hold")


def test_npz_deflate_bomb_of_frames_no_scanner_makes(files):
    d, npz, _, _, zeros = files
    members = [m for m in _npz_members(npz) if m[0] != "images.npy"]
    shape = (10, 16384, 16384)
    head = _npy_header(shape)
    comp = deflate_zeros(head, 2560)
    members.append(("images.npy", comp, 8, 0, len(comp), len(head) + int(np.prod(shape))))
    (d / "bomb.npz").write_bytes(zip_bytes(members))
    _refused_quickly(d / "bomb.npz", r"key 'images': its header describes frames of "
                                     r"\(16384, 16384\)")


def test_gzip_nrrd_and_zlib_plus_inflating_to_2_5_gib(files):
    """pynrrd inflated the whole stream before comparing sizes (2.5 GiB for 2.6 MB)."""
    d, _, mha, nrrd, zeros = files
    lines, _ = split_nrrd(nrrd)
    gz = b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\x03" + zeros + bytes(8)
    (d / "bomb.nrrd").write_bytes(join_nrrd(nrrd_set(lines, "encoding", "gzip"), gz))
    _refused_quickly(d / "bomb.nrrd", r"the gzip data inflates to more than the \d+ bytes")
    head, _ = split_mha(mha)
    blob = b"\x78\xda" + zeros + bytes(4)
    head = set_field(set_field(head, "DimSize", "16384 16384 10"), "CompressedDataSize",
                     str(len(blob)))
    (d / "bomb.seq.mha").write_bytes(join_mha(head, blob))
    _refused_quickly(d / "bomb.seq.mha", r"DimSize describes frames of \(16384, 16384\)")
