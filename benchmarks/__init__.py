"""Benchmarks behind ``fedtrack bench``: deployment latency/throughput and the estimation core."""
