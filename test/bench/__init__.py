"""Smoke tests of the benchmarks in bench/: each runs small and its figures are checked."""
