"""Benchmarks: speed, memory and accuracy tables (``python -m benchmarks SUITE``)."""
