"""The repository's benchmarks: speed checks (``python benchmarks/NAME.py``), studies of what the
method achieves (``python -m benchmarks.studies.NAME`` from the repository root) and the helpers they
share (:mod:`benchmarks.common`)."""
