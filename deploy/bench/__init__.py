"""Benchmarks of the learning core in the simulation (these import :mod:`sim`)."""
