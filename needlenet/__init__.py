"""needlenet: real-time needle tracking in ultrasound.

The runtime package. It imports numpy, scipy, OpenCV, scikit-image and onnxruntime only;
torch and Lightning belong to the ``training`` package and are never imported here.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
