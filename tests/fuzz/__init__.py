"""The fuzz suite of issue 21: a seeded generator of bad inputs (:mod:`.cases`), a runner that
sends them through ``needlenet.cli.main`` in a worker process bounded in time and memory
(:mod:`.runner`), and the CI sample (``test_fuzz.py``).

``python -m tests.fuzz.runner --cases 2000 --seed 0`` runs the full set on demand.
"""
