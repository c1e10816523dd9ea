"""Benchmarks (`pf-slam bench ...`)."""
