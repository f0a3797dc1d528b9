"""Accuracy benchmarks (not tests): ``python -m benchmarks.accuracy``."""
