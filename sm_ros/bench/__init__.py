"""Benchmarks of sm_ros: ``python -m sm_ros.bench --help`` (doc/benchmarks.md)."""
