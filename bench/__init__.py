"""Benchmarks (not tests): each prints its figures and ratios against the bare OpenCV calls doing
the same work, measured in one run (docs/performance.md). Run them as ``python -m bench.<name>``."""
