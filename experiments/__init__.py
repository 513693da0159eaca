"""Scripts that reproduce the results: from the repository's folder, ``python -m experiments.NAME``.

Never imported by the package. Helpers shared by several scripts and by the tests are modules here too
(``benchmark_cases``, ``peers``, ``depth_references``, ``real_data``), imported as ``experiments.NAME``.
"""
