"""Studies of what the method achieves and where it falls short, run from the repository root as
``python -m benchmarks.studies.NAME``."""
