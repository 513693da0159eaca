"""Speed and memory scripts: from the repository's folder, ``python -m benchmarks.NAME``.

Each times the package against a peer or an earlier revision in the same run (ratios, not absolute
seconds). Never imported by the package nor by its tests; a benchmark may import a helper of
``experiments`` (``experiments.peers``) or of ``tests`` (``tests.fff_writer``).
"""
