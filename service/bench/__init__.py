"""Benchmarks: speed measured, never asserted in tests."""
