"""Geometry and material removal: dexel grids, tools, sweeps, checks, traces.

Pure numpy (+ numba for the hot kernels). No I/O beyond reading the files it is
given, no plotting, and no imports from :mod:`drivers` or :mod:`monitor`.
Units: millimetres and seconds.
"""

from sim.errors import SimError, InputError
from sim.kernel_cache import use_fingerprinted_cache
from sim.tolerance import Tolerance

use_fingerprinted_cache()   # before any kernel module is imported (see sim.kernel_cache)

__all__ = ["InputError", "SimError", "Tolerance"]
