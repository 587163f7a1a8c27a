"""The generator of the external in-plane test set (``python -m
needlenet.bench.external.generate``) and of the axial one (``--set axial``). It needs PyMUST
(``pip install 'needlenet[external]'``), which only its generator modules import; the committed
sets live in ``needlenet/data/external`` and ``needlenet/data/external_axial``."""
