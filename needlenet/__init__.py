"""needlenet: real-time needle tracking in ultrasound.

The runtime package. It imports numpy, scipy, OpenCV, scikit-image and onnxruntime only;
torch and Lightning belong to the ``training`` package and are never imported here.

Tracking frames of your own, as ``needlenet track`` does, from Python::

    import needlenet

    tracker = needlenet.make_tracker("inplane")  # the default method and features
    for t, image in frames:  # (H, W) gray, depth first
        est = tracker.update(needlenet.Frame.from_image(image, spacing_mm=0.1, t=t))
        if est.status is needlenet.Status.TRACKING:
            use(est.tip_mm, est.direction, est.covariance)  # mm: (x lateral, z depth)

``needlenet.load_recording(path)`` reads a recording file as a sequence whose frames
``tracker.run(sequence)`` tracks.
"""

__version__ = "0.1.0"

# the names a user's script needs, imported when first used: `import needlenet` stays light
_LAZY = {"make_tracker": "needlenet.trackers", "Status": "needlenet.trackers",
         "NeedleEstimate": "needlenet.trackers", "Frame": "needlenet.features",
         "load_recording": "needlenet.io"}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'needlenet' has no attribute {name!r}")
