"""Benchmarks that print figures (a table and JSON); run with `make bench`."""
