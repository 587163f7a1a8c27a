"""PLUS sequence metafiles: agreement with SimpleITK both ways, orientation codes, bad files."""

import numpy as np
import pytest

from needlenet.io import PlusSequence, RecordingError, read_plus, write_plus
from needlenet.io._atomic import atomic_write

sitk = pytest.importorskip("SimpleITK")


def _frames(seed=0, shape=(5, 31, 23)):
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def _pose(i):
    a = 0.1 * i
    m = np.eye(4)
    m[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    m[:3, 3] = [1.5 * i, -2.0, 0.25 + i / 3]
    return m


def _plus(images):
    T = images.shape[0]
    return PlusSequence(
        images=images, spacing_mm=np.array([0.2, 0.15]), origin_mm=np.array([1.5, -3.25]),
        timestamps_s=10.0 + np.arange(T) / 7.0,
        transforms={"ProbeToReference": np.stack([_pose(i) for i in range(T)])},
        transform_ok={"ProbeToReference": np.arange(T) != 2})


@pytest.mark.parametrize("name", ["a.seq.mha", "a.igs.mha", "a.mhd"])
@pytest.mark.parametrize("compress", [True, False])
def test_simpleitk_reads_what_needlenet_writes(tmp_path, name, compress):
    im = _frames(1)
    written = write_plus(tmp_path / name, _plus(im), compress=compress)
    assert written[0] == tmp_path / name and len(written) == (2 if name.endswith("mhd") else 1)
    img = sitk.ReadImage(str(tmp_path / name))
    np.testing.assert_array_equal(sitk.GetArrayFromImage(img), im)
    # ElementSpacing / Offset are (x, y, t): lateral first; the sequence file is [depth, lateral]
    assert img.GetSpacing() == pytest.approx((0.15, 0.2, 1.0))
    assert img.GetOrigin() == pytest.approx((-3.25, 1.5, 0.0))
    assert img.GetMetaData("Seq_Frame0002_ProbeToReferenceTransformStatus") == "INVALID"
    assert img.GetMetaData("Seq_Frame0003_ProbeToReferenceTransformStatus") == "OK"
    m = np.array(img.GetMetaData("Seq_Frame0003_ProbeToReferenceTransform").split(), float)
    np.testing.assert_allclose(m.reshape(4, 4), _pose(3), rtol=0, atol=1e-12)
    assert float(img.GetMetaData("Seq_Frame0004_Timestamp")) == 10.0 + 4 / 7.0
    assert img.GetMetaData("UltrasoundImageOrientation") == "MF"


@pytest.mark.parametrize("name", ["s.seq.mha", "s.mhd"])
@pytest.mark.parametrize("compress", [True, False])
def test_needlenet_reads_what_simpleitk_writes(tmp_path, name, compress):
    im = _frames(2)
    img = sitk.GetImageFromArray(im)
    img.SetSpacing((0.15, 0.2, 1.0))
    img.SetOrigin((-3.25, 1.5, 0.0))
    for i in range(im.shape[0]):
        f = f"Seq_Frame{i:04d}_"
        pose = " ".join(map(repr, _pose(i).ravel().tolist()))
        img.SetMetaData(f + "ProbeToReferenceTransform", pose)
        img.SetMetaData(f + "ProbeToReferenceTransformStatus", "INVALID" if i == 1 else "OK")
        img.SetMetaData(f + "Timestamp", repr(0.05 * i))
        img.SetMetaData(f + "ImageStatus", "OK")
    img.SetMetaData("UltrasoundImageOrientation", "MF")
    sitk.WriteImage(img, str(tmp_path / name), useCompression=compress)
    p = read_plus(tmp_path / name)
    np.testing.assert_array_equal(p.images, im)
    np.testing.assert_allclose(p.spacing_mm, [0.2, 0.15])
    np.testing.assert_allclose(p.origin_mm, [1.5, -3.25])
    np.testing.assert_allclose(p.timestamps_s, 0.05 * np.arange(5))
    np.testing.assert_allclose(p.transforms["ProbeToReference"][3], _pose(3), atol=1e-12)
    np.testing.assert_array_equal(p.transform_ok["ProbeToReference"], [1, 0, 1, 1, 1])


def _with_orientation(path, code):
    data = path.read_bytes()
    old = b"UltrasoundImageOrientation = MF\n"
    assert data.count(old) == 1
    path.write_bytes(data.replace(old, f"UltrasoundImageOrientation = {code}\n".encode()))
    return path


@pytest.mark.parametrize("code,flip", [("MF", ()), ("UF", (2,)), ("MN", (1,)),
                                       ("UN", (1, 2)), ("mfa", ())])
def test_orientation_codes_flip_lateral_and_depth(tmp_path, code, flip):
    im = _frames(3, (2, 7, 11))  # asymmetric: every flip changes the frames
    p = write_plus(tmp_path / "o.mha", _plus(im), compress=False)[0]
    got = read_plus(_with_orientation(p, code)).images
    np.testing.assert_array_equal(got, np.flip(im, flip) if flip else im)
    assert not np.array_equal(np.flip(im, 1), im) and not np.array_equal(np.flip(im, 2), im)


def test_volume_sequence_axes_and_elevation_flip(tmp_path):
    vol = _frames(4, (2, 6, 5, 9))  # [depth, elevation, lateral]
    plus = PlusSequence(images=vol, spacing_mm=np.array([0.3, 0.5, 0.2]),
                        origin_mm=np.array([1.0, 2.0, 3.0]), timestamps_s=np.array([0.0, 0.1]))
    p = write_plus(tmp_path / "v.seq.mha", plus, compress=True)[0]
    img = sitk.ReadImage(str(p))
    # PLUS volumes: x lateral, y depth, z elevation
    np.testing.assert_array_equal(sitk.GetArrayFromImage(img), vol.transpose(0, 2, 1, 3))
    assert img.GetSpacing() == pytest.approx((0.2, 0.3, 0.5, 1.0))
    back = read_plus(p)
    np.testing.assert_array_equal(back.images, vol)
    np.testing.assert_allclose(back.spacing_mm, [0.3, 0.5, 0.2])
    np.testing.assert_allclose(back.origin_mm, [1.0, 2.0, 3.0])
    data = p.read_bytes()
    # U flips lateral (x), N flips depth (y), D flips elevation (z): array axes 3, 1 and 2
    for code, axes in ((b"UNA", (1, 3)), (b"MFD", (2,)), (b"UND", (1, 2, 3))):
        p.write_bytes(data.replace(b"UltrasoundImageOrientation = MFA\n",
                                   b"UltrasoundImageOrientation = " + code + b"\n"))
        np.testing.assert_array_equal(read_plus(p).images, np.flip(vol, axes))


def test_colour_and_16_bit_frames_become_gray_uint8(tmp_path):
    rgb = np.random.default_rng(5).integers(0, 256, (2, 6, 8, 3), dtype=np.uint8)
    img = sitk.GetImageFromArray(rgb, isVector=True)
    img.SetSpacing((0.1, 0.1, 1.0))
    sitk.WriteImage(img, str(tmp_path / "c.mha"))
    got = read_plus(tmp_path / "c.mha").images
    want = np.rint(rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114)
    np.testing.assert_array_equal(got, want.astype(np.uint8))
    u16 = np.arange(2 * 4 * 5, dtype=np.uint16).reshape(2, 4, 5) * 1000
    sitk.WriteImage(sitk.GetImageFromArray(u16), str(tmp_path / "u.mha"))
    p = read_plus(tmp_path / "u.mha")
    assert p.images.dtype == np.uint8 and p.images.min() == 0 and p.images.max() == 255
    assert p.intensity_range == (0.0, 39000.0)


# -- bad files --------------------------------------------------------------------------------

@pytest.fixture
def good(tmp_path):
    return write_plus(tmp_path / "g.seq.mha", _plus(_frames(6)), compress=False)[0]


@pytest.mark.parametrize("compress", [False, True])
def test_truncated_file_is_named(tmp_path, compress):
    p = write_plus(tmp_path / "t.seq.mha", _plus(_frames(7)), compress=compress)[0]
    p.write_bytes(p.read_bytes()[:-200])
    with pytest.raises(RecordingError, match=r"t\.seq\.mha: truncated"):
        read_plus(p)


def test_header_sizes_that_do_not_match_the_data(good):
    data = good.read_bytes()
    good.write_bytes(data.replace(b"DimSize = 23 31 5\n", b"DimSize = 23 30 5\n"))
    with pytest.raises(RecordingError, match="g.seq.mha: sizes do not match the data"):
        read_plus(good)
    good.write_bytes(data.replace(b"DimSize = 23 31 5\n", b"DimSize = 23 31\n"))
    with pytest.raises(RecordingError, match="field DimSize has 2 values, expected 3"):
        read_plus(good)


@pytest.mark.parametrize("old,new,msg", [
    (b"UltrasoundImageOrientation = MF\n", b"UltrasoundImageOrientation = XY\n",
     "UltrasoundImageOrientation = 'XY' is unknown"),
    (b"ElementType = MET_UCHAR\n", b"ElementType = MET_BOGUS\n", "ElementType = 'MET_BOGUS'"),
    (b"Seq_Frame0001_Timestamp = ", b"Seq_Frame0009_Timestamp = ",
     "Seq_Frame0009_Timestamp: frame 9 is beyond"),
    (b"ElementSpacing = 0.15 0.2 1\n", b"ElementSpacing = 0.15 x 1\n",
     "field ElementSpacing = '0.15 x 1' is not a list of numbers"),
])
def test_bad_header_fields_are_named(good, old, new, msg):
    data = good.read_bytes()
    assert data.count(old) == 1
    good.write_bytes(data.replace(old, new))
    with pytest.raises(RecordingError, match=msg.replace("(", r"\(").replace(")", r"\)")):
        read_plus(good)


def test_bad_transform_is_named(good):
    data = good.read_bytes()
    start = data.index(b"Seq_Frame0001_ProbeToReferenceTransform = ")
    end = data.index(b"\n", start)
    good.write_bytes(data[:start] + b"Seq_Frame0001_ProbeToReferenceTransform = 1 0 0"
                     + data[end:])
    with pytest.raises(RecordingError, match="Seq_Frame0001_ProbeToReferenceTransform must be 16"):
        read_plus(good)


def test_not_a_metaimage(tmp_path):
    p = tmp_path / "x.mha"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    with pytest.raises(RecordingError, match="x.mha: "):
        read_plus(p)
    p.write_bytes(b"ObjectType = Image\nNDims = 3\n")
    with pytest.raises(RecordingError, match="truncated header"):
        read_plus(p)


def test_nothing_partial_over_an_existing_output(tmp_path):
    out = tmp_path / "r.seq.mha"
    out.write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="r.seq.mha exists"):
        write_plus(out, _plus(_frames(8)))
    assert out.read_bytes() == b"precious"

    def failing(fh):
        fh.write(b"half a file")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write({out: failing}, overwrite=True)
    assert out.read_bytes() == b"precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.seq.mha"]  # no temp file left
    write_plus(out, _plus(_frames(8)), overwrite=True)
    np.testing.assert_array_equal(read_plus(out).images, _frames(8))
