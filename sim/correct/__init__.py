"""Tool path correction (Huang & Oliver 1994, section 4): gouging moves made safe.

* :mod:`sim.correct.kernels` - compiled: the gouge of a pose or a move's sweep, the guide
  vector (eq. 7), the recursive subdivision (Fig. 14).
* :mod:`sim.correct.gouge` - :class:`GougeProbe`, the design as the kernels read it.
* :mod:`sim.correct.path` - :func:`correct_moves`, a whole move table.
* :mod:`sim.correct.rewrite` - the corrected path written back into the program's text.
"""
