"""Configuration of execution on Dask."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class ExecutionConfig(ConfigSection):
    """The ``execution`` section: how the run uses Dask."""

    scheduler: str = param(
        "local", "'local' (LocalCluster), 'sync' (in-process) or a scheduler address tcp://host:port"
    )
    workers: int = param(0, "LocalCluster workers; 0 = from the machine's cores", lo=0, hi=4096)
    threads_per_worker: int = param(0, "Threads per LocalCluster worker; 0 = automatic", lo=0, hi=1024)
    host: str = param("127.0.0.1", "Address LocalCluster binds to (loopback by default)")
    retries: int = param(2, "Retries of a failed task (lost worker)", lo=0, hi=100)
    no_worker_timeout_s: float = param(
        300.0, "A run whose Dask cluster has had no worker for this long ends with NoWorkerError (the units finished "
        "so far stay committed; the same command resumes); 0 = wait for workers for ever", unit="s", lo=0.0, hi=604800.0,
    )
    adjust_resource: str = param(
        "auto", "Run bundle adjustments (memory-heavy) one per worker through the Dask worker resource "
        "'adjust_slots': 'auto' uses it on a LocalCluster and on a scheduler whose workers advertise it "
        "(dask worker --resources adjust_slots=1, as the cluster/ scripts start them); 'on' always (a task waits "
        "for such a worker); 'off' never", choices=("auto", "on", "off"),
    )
