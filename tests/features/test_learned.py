"""The learned FeatureSource: maps on the frame's grid, clear errors for bad models."""

import numpy as np
import pytest

import synth
from needlenet.features import Frame, LearnedFeatures, ModelError

torch = pytest.importorskip("torch")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    from training.export import export_onnx
    from training.networks import NeedleNet2D, NeedleNet3D

    d = tmp_path_factory.mktemp("models")
    torch.manual_seed(0)
    export_onnx(NeedleNet2D().eval(), "inplane", 0.2, d / "i.onnx")
    export_onnx(NeedleNet3D().eval(), "volume", 0.5, d / "v.onnx")
    return d


@pytest.mark.parametrize("shape,spacing", [((101, 77), (0.13, 0.27)), ((64, 64), (0.2, 0.2)),
                                           ((33, 250), (0.31, 0.09))])
def test_maps_on_the_frame_grid(models, shape, spacing):
    f = LearnedFeatures(models / "i.onnx", "inplane")
    img = np.random.default_rng(0).integers(0, 255, shape, dtype=np.uint8)
    lk = f.likelihood(Frame(img, synth.Grid(shape, spacing, (0.0, 0.0))))
    assert lk.shaft.shape == shape and lk.tip.shape == shape
    assert lk.shaft.min() >= 0 and lk.shaft.max() <= 1


def test_volume_maps_and_roi(models):
    f = LearnedFeatures(models / "v.onnx", "volume", margin_mm=1.0)
    shape = (37, 29, 41)
    img = np.random.default_rng(1).integers(0, 255, shape, dtype=np.uint8)
    fr = Frame(img, synth.Grid(shape, (0.4, 0.6, 0.35), (0.0, 0.0, 0.0)))
    full = f.likelihood(fr)
    assert full.shaft.shape == shape
    roi = (slice(10, 25), slice(5, 20), slice(12, 30))
    part = f.likelihood(fr, roi=roi)
    assert part.shaft.shape == shape
    assert part.shaft[0, 0, 0] == 0.0  # outside the ROI and its context margin


def test_median_normalisation_is_gain_invariant(tmp_path):
    """A "median" model sees I / median(non-zero I): doubling the gain changes nothing, and
    an ROI is normalised by its whole frame's level, so it matches the full-frame maps."""
    from needlenet.features._resample import image_level, normalize
    from training.export import export_onnx
    from training.networks import NeedleNet3D

    torch.manual_seed(1)
    export_onnx(NeedleNet3D().eval(), "volume", 0.5, tmp_path / "m.onnx",
                normalization="median")
    f = LearnedFeatures(tmp_path / "m.onnx", "volume", margin_mm=6.0)
    assert f.normalization["mode"] == "median"
    shape = (32, 28, 36)
    img = np.random.default_rng(2).integers(10, 120, shape).astype(np.uint8)
    img[:, :, :4] = 0  # outside a sector: left out of the level
    assert image_level(img) == pytest.approx(np.median(img[img > 0]), abs=1.0)
    x = np.float32([0, 40, 80])
    np.testing.assert_allclose(normalize(x, f.normalization, 40.0), [-1, 0, 1])
    g = synth.Grid(shape, (0.5, 0.5, 0.5), (0.0, 0.0, 0.0))
    a = f.likelihood(Frame(img, g)).shaft
    b = f.likelihood(Frame((img * 2).astype(np.uint8), g)).shaft
    np.testing.assert_allclose(a, b, atol=1e-4)
    roi = (slice(8, 24), slice(8, 20), slice(10, 26))
    part = f.likelihood(Frame(img, g), roi=roi).shaft
    inner = (slice(12, 20), slice(12, 16), slice(14, 22))  # far from the context's edges
    np.testing.assert_allclose(part[inner], a[inner], atol=2e-3)


def test_bad_models_are_named(models, tmp_path):
    with pytest.raises(ModelError, match="does not exist"):
        LearnedFeatures(tmp_path / "none.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"this is not a model")
    with pytest.raises(ModelError, match="cannot be loaded"):
        LearnedFeatures(bad)
    with pytest.raises(ModelError, match="is a 'volume' model, not 'inplane'"):
        LearnedFeatures(models / "v.onnx", "inplane")


@pytest.mark.parametrize("modality", ["inplane", "axial", "volume"])
def test_shipped_model_finds_the_needle(modality):
    """Each shipped model puts its maximum on the needle of a seeded high-contrast frame."""
    from needlenet.features import learned_features
    from needlenet.features._learned import shipped_model_path

    try:
        shipped_model_path(modality)
    except ModelError:
        pytest.skip(f"no shipped {modality} model in this checkout")
    src = learned_features(modality)
    if modality == "inplane":
        seq = synth.generate("inplane", seed=40_000_001, frames=1, start_length_mm=25.0,
                             angle_deg=40.0, background="homogeneous",
                             imaging_overrides={"tissue_gray": 50.0}, cr=2.0)
    elif modality == "axial":
        seq = synth.generate("axial", seed=40_000_002, frames=6, background="homogeneous",
                             cr=2.2)
    else:
        seq = synth.generate("volume", seed=40_000_003, frames=1, output_size=96, cr=4.0,
                             alpha_deg=30.0, background="homogeneous", start_length_mm=20.0)
    i = seq.n_frames - 1
    g = seq.grid()
    lk = src.likelihood(Frame(seq.images[i], g))
    # shaft: the maximum lies within 1 mm of the needle the model marks: its centre line, or
    # the wall facing the probe (2D models: the trackers add the radius)
    from needlenet.features._learned import wall_offsets

    peak = np.array(np.unravel_index(int(np.argmax(lk.shaft)), g.shape), float)
    p = g.index_to_points(peak)
    if seq.ndim == 2:
        p = np.array([p[0], 0.0, p[1]])
    cl = np.asarray(seq.centerline_mm[i], float)
    tip_true = np.asarray(seq.tip_mm[i], float)
    if src.target_reference == "wall":
        off = wall_offsets(cl, seq.meta["needle"]["radius_mm"])
        cl = cl + off
        tip_true = tip_true + off[-1][[0, 2]]
    assert np.min(np.linalg.norm(cl - p, axis=1)) < 1.0
    tp = np.array(np.unravel_index(int(np.argmax(lk.tip)), g.shape), float)
    tip_error = np.linalg.norm(g.index_to_points(tp) - tip_true)
    if modality == "inplane":  # the tip channel: its maximum within 1 mm of the labelled tip
        assert tip_error < 1.0
    elif modality == "volume":
        # the small 3D model's tip channel marks the tip but not only it (its arg-max can be a
        # false tip elsewhere; the volume trackers find the tip from the shaft map's drop):
        # the map at the true tip is at least half its maximum
        at_tip = lk.tip[tuple(np.rint(g.points_to_index(tip_true)).astype(int))]
        assert at_tip >= 0.5 * lk.tip.max()


def test_robust_normalisation_is_invariant_to_gain_and_dynamic_range(tmp_path):
    """Log compression makes a gain change a grey offset and a dynamic-range change a grey
    scale; the "robust" input (I - median) / (1.4826 MAD) over non-zero pixels ignores both,
    zero (black margin) pixels read a fixed value, and the model's metadata names the mode."""
    from needlenet.features._resample import NORMALIZATIONS, image_statistics, normalize
    from training.export import export_onnx
    from training.networks import NeedleNet2D

    norm = NORMALIZATIONS["robust"]
    rng = np.random.default_rng(3)
    img = rng.normal(80.0, 12.0, (120, 90)).clip(1, 255).astype(np.float32)
    img[40:44, 10:80] = 200.0  # a bright line
    img[:, :8] = 0.0  # a black capture margin
    med, spread = image_statistics(img)
    inside = img[img > 0]
    assert med == pytest.approx(np.median(inside))
    assert spread == pytest.approx(1.4826 * np.median(np.abs(inside - med)))
    z = normalize(img, norm)
    for scale, offset in ((1.7, -35.0), (0.55, 40.0)):
        changed = np.where(img > 0, img * np.float32(scale) + np.float32(offset), 0.0)
        np.testing.assert_allclose(normalize(changed.astype(np.float32), norm), z, atol=1e-5)
    assert np.all(z[:, :8] == norm["zero_value"])
    assert z.min() >= norm["clip"][0] and z.max() <= norm["clip"][1]
    torch.manual_seed(2)
    export_onnx(NeedleNet2D().eval(), "inplane", 0.2, tmp_path / "r.onnx", normalization="robust")
    f = LearnedFeatures(tmp_path / "r.onnx", "inplane")
    assert f.normalization == norm
    g = synth.Grid(img.shape, (0.2, 0.2), (0.0, 0.0))
    frame = np.rint(img).astype(np.uint8)
    brighter = np.where(frame > 0, frame.astype(np.float32) * 0.8 + 30, 0)
    a = f.likelihood(Frame(frame.astype(np.float32), g)).shaft
    b = f.likelihood(Frame(brighter.astype(np.float32), g)).shaft
    np.testing.assert_allclose(a, b, atol=1e-4)
