"""Comparisons of pipeline results with the synthetic truth (used by tests and reports; reads truth, never the pipeline)."""
