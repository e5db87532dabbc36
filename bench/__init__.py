"""Benchmarks of fleetsim that anyone can run: ``python -m bench.fleet_bench --help``."""
