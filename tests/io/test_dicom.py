"""DICOM ultrasound recordings (needlenet/io/_dicom.py): a scanner's cine loop read with the
spacing, image region and frame times it carries, its pixels decoded by pydicom and Pillow
and checked against the frames written (OpenCV's JPEG encoder on the other side)."""

import json

import numpy as np
import pytest

import synth
from needlenet.cli import main
from needlenet.io import RecordingError, load_recording
from needlenet.trackers import make_tracker
from tests.dicom_files import region, write_dicom

MARGIN_Y, MARGIN_X = 40, 50  # the screen around the image: text, scales


@pytest.fixture(scope="module")
def seq():
    return synth.generate("inplane", seed=21, frames=5)


def _screen(images: np.ndarray) -> np.ndarray:
    """The frames on a scanner's screen: black margins with a line of bright 'text'."""
    T, H, W = images.shape
    scr = np.zeros((T, H + MARGIN_Y + 20, W + MARGIN_X + 30), np.uint8)
    scr[:, MARGIN_Y:MARGIN_Y + H, MARGIN_X:MARGIN_X + W] = images
    scr[:, 5:15, 5:120] = 220
    return scr


def _region_of(seq, reference=True):
    T, H, W = seq.images.shape
    ref = (0, 0, seq.origin_mm[1] / 10.0, seq.origin_mm[0] / 10.0) if reference else None
    return region(MARGIN_X, MARGIN_Y, MARGIN_X + W - 1, MARGIN_Y + H - 1, *seq.spacing_mm,
                  reference=ref)


def test_a_cine_loop_is_read_with_its_region_spacing_origin_and_frame_time(seq, tmp_path):
    """The region's box cuts the screen away, its PhysicalDelta gives mm, its reference
    pixel the origin, FrameTime the times: the frames, grid and tracks of the sequence."""
    p = write_dicom(tmp_path / "loop.dcm", _screen(np.asarray(seq.images)),
                    regions=[_region_of(seq)], frame_time_ms=50.0)
    rec = load_recording(p)
    np.testing.assert_array_equal(np.asarray(rec.images), seq.images)
    np.testing.assert_allclose(rec.spacing_mm, seq.spacing_mm, rtol=1e-9)
    np.testing.assert_allclose(rec.origin_mm, seq.origin_mm, atol=1e-9)
    np.testing.assert_allclose(rec.timestamps_s, 0.05 * np.arange(5), atol=1e-12)
    assert rec.meta["format"] == "dicom"
    assert rec.meta["dicom"]["geometry_from"] == "ultrasound region"
    assert rec.meta["crop"] == [MARGIN_X, MARGIN_Y, seq.images.shape[2], seq.images.shape[1]]
    a = make_tracker("inplane", "line", "learned", seed=0).run(seq)
    b = make_tracker("inplane", "line", "learned", seed=0).run(rec)
    assert [e.status for e in a] == [e.status for e in b]
    for x, y in zip(a, b, strict=True):
        if x.tip_mm is not None:
            np.testing.assert_allclose(x.tip_mm, y.tip_mm, atol=1e-9)


def test_a_user_crop_replaces_the_region_and_keeps_the_physical_frame(seq, tmp_path):
    p = write_dicom(tmp_path / "loop.dcm", _screen(np.asarray(seq.images)),
                    regions=[_region_of(seq)])
    rec = load_recording(p, crop=(MARGIN_X + 10, MARGIN_Y + 20, 100, 200))
    np.testing.assert_array_equal(np.asarray(rec.images), seq.images[:, 20:220, 10:110])
    np.testing.assert_allclose(rec.origin_mm, np.asarray(seq.origin_mm) + [2.0, 1.0],
                               atol=1e-9)


def test_a_jpeg_colour_loop_decodes_to_the_frames_within_jpeg_error(seq, tmp_path):
    """YBR_FULL_422 JPEG frames (OpenCV's encoder) decoded by pydicom and Pillow: gray
    within JPEG's error of the frames written; a green mark drawn in the image is filled
    in from the echo around it, as in a video."""
    im = np.asarray(seq.images)
    rgb = np.repeat(_screen(im)[..., None], 3, axis=-1)
    y0, x0 = MARGIN_Y + 300, MARGIN_X + 50
    rgb[:, y0:y0 + 3, x0:x0 + 200] = (0, 255, 0)  # a drawn guide line
    p = write_dicom(tmp_path / "colour.dcm", rgb, regions=[_region_of(seq)],
                    compression="jpeg")
    rec = load_recording(p)
    assert rec.meta["dicom"]["transfer_syntax"].startswith("JPEG Baseline")
    assert rec.meta["dicom"]["photometric"] == "YBR_FULL_422"
    got = np.asarray(rec.images).astype(float)
    away = np.ones(im.shape[1:], bool)
    away[295:310, 45:255] = False
    err = np.abs(got - im)[:, away]
    assert err.mean() < 2.5 and np.percentile(err, 99) < 12
    green_luma = 0.587 * 255
    line = got[:, 300:303, 60:240]
    assert abs(line.mean() - im[:, 300:303, 60:240].mean()) < 0.3 * green_luma


def _palette(path, red, green, blue):
    """The file at ``path`` made a PALETTE COLOR image with these 256-entry 8-bit tables."""
    import pydicom

    ds = pydicom.dcmread(path)
    ds.PhotometricInterpretation = "PALETTE COLOR"
    for name, table in (("Red", red), ("Green", green), ("Blue", blue)):
        key = f"{name}PaletteColorLookupTableDescriptor"
        setattr(ds, key, [256, 0, 8])
        ds[key].VR = "US"
        setattr(ds, f"{name}PaletteColorLookupTableData", np.asarray(table, np.uint8).tobytes())
    ds.save_as(path, enforce_file_format=True)
    return path


@pytest.mark.parametrize("kind", ["rle", "monochrome1", "12-bit", "ybr", "palette"])
def test_lossless_encodings_read_back_exactly(seq, tmp_path, kind):
    from pydicom.pixels import convert_color_space

    im = np.asarray(seq.images)
    ramp = np.arange(256)
    if kind == "ybr":  # uncompressed YBR_FULL: pydicom's conversion back to RGB, then luma
        rgb = np.repeat(im[..., None], 3, axis=-1)
        ybr = np.stack([convert_color_space(f, "RGB", "YBR_FULL") for f in rgb])
        p = write_dicom(tmp_path / "f.dcm", ybr, pixel_spacing=[0.1, 0.1],
                        photometric="YBR_FULL")
    elif kind == "palette":  # indices through the tables: gray tables, the index reversed
        p = _palette(write_dicom(tmp_path / "f.dcm", 255 - im, pixel_spacing=[0.1, 0.1]),
                     255 - ramp, 255 - ramp, 255 - ramp)
    elif kind == "rle":
        p = write_dicom(tmp_path / "f.dcm", im, pixel_spacing=[0.1, 0.1], compression="rle")
    elif kind == "monochrome1":  # the lowest value is white
        p = write_dicom(tmp_path / "f.dcm", 255 - im, pixel_spacing=[0.1, 0.1],
                        photometric="MONOCHROME1")
    else:  # 12 bits stored in 16: the full stored range to 0..255
        stored = (im.astype(np.int64) * 4095 // 255).astype(np.uint16)
        p = write_dicom(tmp_path / "f.dcm", stored, pixel_spacing=[0.1, 0.1], bits_stored=12)
    rec = load_recording(p)
    got = np.asarray(rec.images).astype(int)
    assert np.abs(got - im).max() <= (1 if kind in ("12-bit", "ybr") else 0)
    assert rec.meta["dicom"]["geometry_from"] == "PixelSpacing"
    assert rec.origin_mm.tolist() == [0.0, 0.0]


def test_frame_times_from_the_vector_or_a_rate(seq, tmp_path):
    im = np.asarray(seq.images)
    p = write_dicom(tmp_path / "v.dcm", im, pixel_spacing=[0.1, 0.1],
                    frame_time_vector=[0.0, 40.0, 40.0, 60.0, 50.0])
    np.testing.assert_allclose(load_recording(p).timestamps_s, [0, 0.04, 0.08, 0.14, 0.19])
    p = write_dicom(tmp_path / "r.dcm", im, pixel_spacing=[0.1, 0.1], frame_time_ms=None)
    with pytest.raises(RecordingError, match="FrameTime.*--fps"):
        load_recording(p)
    np.testing.assert_allclose(load_recording(p, fps=25).timestamps_s, 0.04 * np.arange(5))


def test_without_calibration_the_error_asks_for_spacing(seq, tmp_path):
    """No region in cm and no PixelSpacing: the error names what the file lacks and
    --spacing; with the spacing given the loop reads."""
    im = np.asarray(seq.images)
    no_units = region(0, 0, im.shape[2] - 1, im.shape[1] - 1, 0.1, 0.1, units=0)
    p = write_dicom(tmp_path / "bare.dcm", im, regions=[no_units])
    with pytest.raises(RecordingError, match=r"bare\.dcm: no pixel spacing .*"
                       r"SequenceOfUltrasoundRegions.*--spacing"):
        load_recording(p)
    rec = load_recording(p, spacing_mm=0.1)
    assert rec.images.shape == im.shape and rec.spacing_mm.tolist() == [0.1, 0.1]


def test_of_two_calibrated_regions_the_largest_tissue_image_is_taken(seq, tmp_path):
    im = np.asarray(seq.images)
    T, H, W = im.shape
    scr = np.zeros((T, H, 2 * W + 10), np.uint8)
    scr[:, :, :W] = im
    small = region(W + 10, 0, W + 109, 99, 0.3, 0.3)  # a thumbnail: smaller
    doppler = region(W + 10, 0, 2 * W + 9, H - 1, 0.2, 0.2, data_type=3)  # not tissue
    p = write_dicom(tmp_path / "two.dcm", scr,
                    regions=[small, doppler, region(0, 0, W - 1, H - 1, 0.1, 0.1)])
    rec = load_recording(p)
    np.testing.assert_array_equal(np.asarray(rec.images), im)
    assert any("3 calibrated image regions" in w for w in rec.meta["warnings"])


def test_bad_dicom_files_are_clear_errors(seq, tmp_path):
    im = np.asarray(seq.images)
    T, H, W = im.shape
    outside = region(0, 0, W, H - 1, 0.1, 0.1)  # one column past the image
    p = write_dicom(tmp_path / "out.dcm", im, regions=[outside])
    with pytest.raises(RecordingError, match="region 0 spans columns 0-384 .* outside"):
        load_recording(p)
    fake = tmp_path / "fake.dcm"
    fake.write_bytes(b"\0" * 200)
    with pytest.raises(RecordingError, match=r"fake\.dcm: not a DICOM file"):
        load_recording(fake)
    p = write_dicom(tmp_path / "vol.dcm", im, pixel_spacing=[0.1, 0.1],
                    sop_class="1.2.840.10008.5.1.4.1.1.6.2")
    with pytest.raises(RecordingError, match="Enhanced US Volume"):
        load_recording(p)
    good = write_dicom(tmp_path / "cut.dcm", im, pixel_spacing=[0.1, 0.1]).read_bytes()
    cut = tmp_path / "cut.dcm"
    cut.write_bytes(good[:-im[0].size * 2])  # the last two frames missing
    with pytest.raises(RecordingError, match=r"cut\.dcm: NumberOfFrames .* is 5, but .* hold "
                       "at most 3 frames of 384x500 pixels"):
        load_recording(cut)


def test_a_damaged_compressed_frame_is_an_error_naming_it(seq, tmp_path):
    """Frames are decoded as they are read: the third frame's JPEG data damaged is an
    error naming that frame when the tracker reaches it."""
    import pydicom
    from pydicom.encaps import encapsulate, generate_frames

    p = write_dicom(tmp_path / "bad.dcm", np.asarray(seq.images), pixel_spacing=[0.1, 0.1],
                    compression="jpeg")
    ds = pydicom.dcmread(p)
    frames = list(generate_frames(ds.PixelData, number_of_frames=5))
    frames[2] = b"\xff\xd8" + bytes(len(frames[2]) - 2)
    ds.PixelData = encapsulate(frames)
    ds.save_as(p, enforce_file_format=True)
    rec = load_recording(p)
    assert rec.images[1].shape == seq.images.shape[1:]
    with pytest.raises(RecordingError, match=r"bad\.dcm: frame 2 cannot be decoded"):
        rec.images[2]


def test_an_undecodable_transfer_syntax_is_named_with_a_way_out(seq, tmp_path):
    import pydicom
    from pydicom.encaps import encapsulate
    from pydicom.uid import JPEGLSLossless

    p = write_dicom(tmp_path / "ls.dcm", np.asarray(seq.images), pixel_spacing=[0.1, 0.1])
    ds = pydicom.dcmread(p)
    ds.file_meta.TransferSyntaxUID = JPEGLSLossless
    ds.PixelData = encapsulate([b"\xff\xd8 not JPEG-LS data"] * 5)  # never decoded
    ds.save_as(p, enforce_file_format=True)
    with pytest.raises(RecordingError, match="JPEG-LS Lossless .* cannot decode .*gdcmconv"):
        load_recording(p)


def test_a_dicom_file_without_suffix_tracks_from_the_command_line(seq, tmp_path, capsys):
    """Scanners name exported files IM_0001: read by their signature; `track` needs no
    --spacing, --crop or --fps."""
    p = write_dicom(tmp_path / "IM_0001", _screen(np.asarray(seq.images)),
                    regions=[_region_of(seq)])
    out = tmp_path / "tips.json"
    assert main(["track", str(p), "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    frames = result["frames"]
    assert len(frames) == 5
    # the summary says what geometry the file gave: a user can check it against the scanner
    assert result["summary"]["spacing_mm"] == [float(v) for v in seq.spacing_mm]
    assert result["summary"]["crop"] == [MARGIN_X, MARGIN_Y, *seq.images.shape[:0:-1]]
    tips = [f["tip_mm"] for f in frames if f["status"] == "tracking"]
    assert tips
    truth = np.asarray(seq.tip_mm)[[f["status"] == "tracking" for f in frames]]
    assert np.median(np.linalg.norm(np.asarray(tips) - truth, axis=1)) < 1.0


def test_a_damaged_attribute_that_is_not_needed_is_dropped_with_a_note(seq, tmp_path):
    """A value representation no reader knows, on the manufacturer's name: the loop reads,
    and the note names the attribute; the same damage on Columns is an error naming it."""
    im = np.asarray(seq.images)
    p = write_dicom(tmp_path / "vr.dcm", im, pixel_spacing=[0.1, 0.1])
    data = p.read_bytes()
    for tag, name in ((b"\x08\x00\x70\x00", "(0008,0070)"), (b"\x28\x00\x11\x00", "Columns")):
        j = data.index(tag + (b"LO" if name.startswith("(") else b"US"))
        bad = tmp_path / f"bad{name[:3]}.dcm"
        bad.write_bytes(data[:j + 4] + b"\x55\xf7" + data[j + 6:])
        if name.startswith("("):
            rec = load_recording(bad)
            assert rec.images.shape == im.shape
            assert any("1 damaged DICOM attributes ignored (first: (0008,0070))" in w
                       for w in rec.meta["warnings"])
        else:
            with pytest.raises(RecordingError, match="Columns missing"):
                load_recording(bad)


def test_a_folder_of_dicom_loops_names_one_to_track(seq, tmp_path):
    """A scanner's export folder (DICOMDIR beside IM_0001, IM_0002): each file is a loop."""
    d = tmp_path / "export"
    d.mkdir()
    for name in ("IM_0002", "IM_0001"):
        write_dicom(d / name, np.asarray(seq.images), pixel_spacing=[0.1, 0.1])
    (d / "DICOMDIR").write_bytes(b"\0" * 128 + b"DICM")
    with pytest.raises(RecordingError, match=r"holds 2 DICOM cine loops \(multi-frame files\); "
                       r"each is a recording: track one, e\.g\. .*IM_0001"):
        load_recording(d)


def _series(seq, folder, times=True, over=None):
    """The sequence's frames as single-frame files, written in reverse name order, numbered
    by InstanceNumber, stamped with their acquisition times; ``over``: {frame: attributes}."""
    over = over or {}
    folder.mkdir()
    im = np.asarray(seq.images)
    for i in range(len(im)):
        t = 10 * 3600 + 7 * 60 + 3.25 + float(seq.timestamps_s[i])
        hh, rest = divmod(t, 3600)
        mm, ss = divmod(rest, 60)
        attrs = {"InstanceNumber": i + 1, "SeriesInstanceUID": "1.2.3.4",
                 "AcquisitionTime": f"{int(hh):02d}{int(mm):02d}{ss:09.6f}" if times else None}
        attrs.update(over.get(i, {}))
        whole = region(0, 0, im.shape[2] - 1, im.shape[1] - 1, *seq.spacing_mm)
        write_dicom(folder / f"IM_{len(im) - i:04d}", im[i:i + 1], regions=[whole],
                    frame_time_ms=None, attributes=attrs)
    (folder / "DICOMDIR").write_bytes(b"\0" * 128 + b"DICM")


def test_a_folder_of_single_frames_is_one_recording_in_instance_order(seq, tmp_path):
    _series(seq, tmp_path / "clip")
    rec = load_recording(tmp_path / "clip")
    np.testing.assert_array_equal(np.asarray(rec.images), seq.images)
    np.testing.assert_allclose(rec.timestamps_s, seq.timestamps_s, atol=1e-6)
    np.testing.assert_allclose(rec.spacing_mm, seq.spacing_mm)
    assert rec.meta["dicom"]["files"] == 5


def test_a_series_without_times_asks_for_fps_and_bad_series_are_named(seq, tmp_path):
    _series(seq, tmp_path / "a", times=False)
    with pytest.raises(RecordingError, match=r"no frame times .*--fps"):
        load_recording(tmp_path / "a")
    assert load_recording(tmp_path / "a", fps=20).n_frames == 5
    _series(seq, tmp_path / "b", over={3: {"SeriesInstanceUID": "9.9"}})
    with pytest.raises(RecordingError, match="frames of 2 series"):
        load_recording(tmp_path / "b")
    _series(seq, tmp_path / "c", over={2: {"Rows": 400}})
    with pytest.raises(RecordingError, match=r"IM_0003: 384x400 pixels .* but IM_0005 has "
                       "384x500"):
        load_recording(tmp_path / "c")


@pytest.mark.parametrize("colour", [True, False])
def test_jpeg_frames_decoded_by_opencv_are_pydicoms(seq, tmp_path, colour):
    """JPEG baseline frames (YBR_FULL_422 colour, or gray) go through OpenCV's libjpeg:
    the pixels pydicom's own decode (Pillow, then its YBR conversion) gives (the same bits
    with OpenCV 5.0 and Pillow 13; a grey level of rounding allowed between other builds)."""
    import pydicom
    from pydicom.pixels import pixel_array

    from needlenet.io._dicom import _libjpeg_frame

    im = np.asarray(seq.images)[:3]
    frames = np.repeat(im[..., None], 3, axis=-1) if colour else im
    if colour:
        frames = frames.copy()
        frames[:, 100:110, 50:90] = (30, 200, 60)
    p = write_dicom(tmp_path / "j.dcm", frames, pixel_spacing=[0.1, 0.1], compression="jpeg")
    ds = pydicom.dcmread(p)
    for i in range(3):
        a = _libjpeg_frame(ds, i).astype(int)
        b = pixel_array(ds, index=i).astype(int)
        assert a.shape == b.shape and np.abs(a - b).max() <= 1

