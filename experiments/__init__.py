"""Scripts that reproduce the results: from the repository's folder, ``python -m experiments.NAME``.

Never imported by the package nor by its tests (only ``tests/experiments/`` tests them). Helpers shared by
several scripts are modules here too (``benchmark_cases``, ``peers``), imported as ``experiments.NAME``; what
the tests use as well lives under ``tests/`` (``fff_writer``, ``depth_references``, ``shared_data``) and is
imported as ``tests.NAME``. The speed and memory scripts live in ``benchmarks/``.
"""
