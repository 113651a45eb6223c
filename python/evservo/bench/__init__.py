"""Benchmarks that go beyond criterion's microbenchmarks: end-to-end rates and latencies."""
