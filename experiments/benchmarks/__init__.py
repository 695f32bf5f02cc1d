"""Benchmarks: each prints its ratios against a reference measured in the same run."""
