"""The generator of the external in-plane test set (``python -m
needlenet.bench.external.generate``), of the axial one (``--set axial``) and of the volume one
(``--set volume``), with their validation sets. It needs PyMUST (``pip install
'needlenet[external]'``), which only its generator modules import; the committed sets live in
``needlenet/data/external``, ``needlenet/data/external_axial`` and
``needlenet/data/external_volume`` (validation: ``validation``, ``validation_axial``,
``validation_volume``)."""
