"""Benchmarks: speed and quality reports printed as Markdown tables (not tests)."""
