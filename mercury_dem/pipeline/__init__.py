"""Orchestration on Dask: the only layer that imports dask/distributed."""
