"""Helpers shared by the benchmarks. The speed checks (``python benchmarks/NAME.py``, which puts
``benchmarks/`` first on ``sys.path``) import them as ``common.NAME``; the studies (``python -m
benchmarks.studies.NAME``) as ``benchmarks.common.NAME``. Within this package they import each other
relatively, so that both work."""
