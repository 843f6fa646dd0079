"""Input/output: the only layer that knows paths, stores and atomic writes."""
