"""The generator of the external in-plane test set (``python -m
needlenet.bench.external.generate``). It needs PyMUST (``pip install 'needlenet[external]'``),
which only its ``generate`` module imports; the committed set lives in
``needlenet/data/external``."""
