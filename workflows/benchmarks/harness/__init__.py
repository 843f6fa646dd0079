"""The one benchmark harness of ``workflows/benchmarks`` (not part of the package; the library never imports it).

* :func:`measure` runs a callable (in a forked child) or a command (a child process) and returns wall, CPU
  (user + system, the child's own children included) and peak resident memory; :func:`interleave` runs
  ours and a reference alternately (A B A B ...), so load on a shared machine falls on both alike;
  :func:`measure_here` times a warm call in this process for the benchmarks that measure one.
* :mod:`harness.memory`: the resident memory of this process (now, peak, a peak window), one definition.
* :mod:`harness.records`: JSON records (benchmark, parameters, commit, machine, date, values) appended to
  ``workflows/benchmarks/records/<benchmark>.jsonl``.
* :mod:`harness.scenarios`: the inputs several benchmarks share (synthetic networks, tiny missions, point
  clouds and gdal_grid, the registration surface, the scipy anchor of the adjustment).
* ``python -m harness headline [--check]`` (from ``workflows/benchmarks``): the headline table of
  ``docs/benchmarks.md`` from the records.

Scripts in ``workflows/benchmarks`` import it by its bare name (a script's own directory is first on
``sys.path``); tests load it with ``tests/benchmarks.load_benchmark``.
"""

from harness.measure import Measurement, interleave, measure, measure_here, ratio_of_medians
from harness.memory import peak_rss_bytes, peak_window, rss_bytes
from harness.records import append_record, machine, read_records

__all__ = ["Measurement", "append_record", "interleave", "machine", "measure", "measure_here", "peak_rss_bytes",
           "peak_window",
           "ratio_of_medians", "read_records", "rss_bytes"]
