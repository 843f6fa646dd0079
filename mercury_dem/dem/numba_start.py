"""Start numba's compiler context without two optional imports a cold ``mercury-dem grid`` never uses.

On the first call of any jitted function in a process, numba's CPU target loads its typing and
lowering registries. Two of them import optional packages:

- ``numba.np.arraymath`` imports ``scipy.linalg.cython_blas`` only to set a flag (``_HAVE_BLAS``)
  that picks the inner product of ``np.cov``/``np.corrcoef`` (BLAS or a plain loop); importing it
  runs ``scipy.linalg``'s ``__init__`` (LAPACK wrappers, scipy's array-API layer, ``numpy.f2py``);
- ``numba.core.typing.cffi_utils`` imports ``cffi`` (and ``pycparser``) to type cffi functions.

The gridding kernels (:mod:`mercury_dem.dem.buckets`, :mod:`mercury_dem.dem.filters`) use neither,
and their compiled code comes from numba's on-disk cache, so nothing about them changes. The two
imports cost a cold ``mercury-dem grid`` ~0.1-0.15 s of CPU before any gridding (measured
2026-11-26, docs/benchmarks/dem.md). :func:`start_numba_lean` makes the first jitted call of the
process with those two imports refused; numba then records "no BLAS" (``np.cov`` in a function
*compiled* later in the same process would use the plain loop) and "no cffi" for this process.
Later imports of scipy or cffi work normally: only the first call is guarded.

Why a meta-path finder and not a numba option: numba has no setting for either import. Used by
the ``grid`` command for its own process only (not by the library or by Dask workers, which import
scipy for other reasons anyway).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

#: Imports refused while numba's context starts (a name or its submodules).
REFUSED = ("scipy.linalg", "cffi")


class _Refuse:
    """An import-system finder that refuses :data:`REFUSED` (an ImportError numba catches)."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if any(name == r or name.startswith(r + ".") for r in REFUSED):
            raise ModuleNotFoundError(f"{name} is not imported while numba starts (mercury_dem.dem.numba_start)",
                                      name=name)
        return None


def start_numba_lean(first_call: Callable[[], object]) -> bool:
    """Run ``first_call`` (a first call of a jitted function) with :data:`REFUSED` unimportable.

    Call it from the main thread before any other thread runs (the refusal is process-wide while
    it lasts). Nothing is refused, and False returned, when numba's registries are already loaded or
    one of the refused packages is already imported (the call then starts numba as usual).
    """
    if "numba.np.arraymath" in sys.modules or any(r in sys.modules for r in REFUSED):
        first_call()
        return False
    finder = _Refuse()
    sys.meta_path.insert(0, finder)
    try:
        first_call()
    except ImportError:  # a numba that needs one of them after all: start it as usual, losing only the saving
        sys.meta_path.remove(finder)
        first_call()
        return False
    else:
        sys.meta_path.remove(finder)
    return True


def start_gridding_kernels() -> bool:
    """:func:`start_numba_lean` with a first call of the DEM smoothing kernel (its cache entry is needed anyway)."""
    import numpy as np

    from mercury_dem.dem.filters import box_mean_nan

    return start_numba_lean(lambda: box_mean_nan(np.zeros((4, 4)), 3))
