"""Benchmarks and reproductions of the paper's experiments (not tests: they print tables)."""
