"""Constants of robust statistics shared by the algorithm packages (one definition each).

Lowest layer (beside ``exceptions``): ``adjust``, ``match``, ``dense``, ``reference`` and ``altimetry``
all scale a median absolute deviation to a standard deviation, and none of them may import another for it.
"""

from __future__ import annotations

#: NMAD factor: 1 / Phi^-1(3/4), the scale that makes the median absolute deviation of normally
#: distributed values a consistent estimate of their standard deviation (``sigma ~ NMAD_FACTOR * MAD``).
#: Rounded to the four decimals used throughout the project (and by xdem/ASP for the NMAD).
NMAD_FACTOR = 1.4826
