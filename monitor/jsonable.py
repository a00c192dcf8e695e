"""JSON for findings and events that carry numpy values (alerts' stream, the run file)."""

from __future__ import annotations

import numpy as np


def json_default(o):
    """``json.dumps(..., default=json_default)``: numpy scalars as Python numbers, arrays
    as (nested) lists, anything else as ``str(o)`` so one odd field never loses a finding."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
