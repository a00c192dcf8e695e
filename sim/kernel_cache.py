"""Where numba keeps the compiled kernels: a folder named after the kernel sources.

numba's cache checks only the file of the function it compiled. A kernel that calls one in
another file (``sweep_kernels.linear.cut_linear_batch`` calls ``dexel_store.subtract_interval``;
``correct.kernels`` calls ``sweep_kernels.shapes.linear_interval``) keeps the callee it was
compiled with, so after that other file changed (an upgrade, a checkout) it would go on
running the old code, silently. Here every kernel is cached in a folder named after a
fingerprint of all the kernel sources (their sizes and modification times): change any one
and everything compiles afresh. The newest few folders are kept, older ones removed.

``NUMBA_CACHE_DIR`` set by the user wins; without a writable cache folder numba keeps its
own default (``__pycache__`` beside the sources).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

#: every module with numba kernels, relative to the project root (a test keeps this list
#: equal to the modules that import numba)
KERNEL_SOURCES = (
    "monitor/render/feed.py",
    "monitor/render/shaded.py",
    "monitor/session.py",
    "sim/bands.py",
    "sim/boolean.py",
    "sim/checks/design_kernels.py",
    "sim/checks/engagement_kernels.py",
    "sim/correct/kernels.py",
    "sim/dexel_store.py",
    "sim/gcode/timing.py",
    "sim/grid.py",
    "sim/solids.py",
    "sim/surface.py",
    "sim/sweep_kernels/batch.py",
    "sim/sweep_kernels/linear.py",
    "sim/sweep_kernels/log.py",
    "sim/sweep_kernels/poses.py",
    "sim/sweep_kernels/shapes.py",
    "sim/sweep_kernels/trace_sink.py",
    "sim/trace_kernels.py",
    "sim/tridexel_surface.py",
)
#: cache folders kept (one per version of the sources seen lately)
KEEP = 3

ROOT = Path(__file__).resolve().parent.parent


def fingerprint(root: Path = ROOT) -> str:
    """Hex digest of the kernel sources' sizes and modification times."""
    h = hashlib.sha1()
    for rel in KERNEL_SOURCES:
        try:
            st = (root / rel).stat()
            h.update(f"{rel}:{st.st_size}:{st.st_mtime_ns};".encode())
        except OSError:
            h.update(f"{rel}:absent;".encode())
    return h.hexdigest()[:16]


def cache_root() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "dexmon" / "numba"


def use_fingerprinted_cache() -> Path | None:
    """Point numba's cache at this version's folder (before any kernel module is imported);
    returns the folder, or None when the user chose one or none can be made."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    folder = cache_root() / fingerprint()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)   # its mtime says when this version was last used
        _prune(folder.parent)
    except OSError:
        return None
    if "numba" in sys.modules:   # numba read its settings already: set them where it reads them
        sys.modules["numba"].config.CACHE_DIR = str(folder)
    else:
        os.environ["NUMBA_CACHE_DIR"] = str(folder)
    return folder


def _prune(parent: Path) -> None:
    """Remove all but the :data:`KEEP` most recently used folders."""
    folders = sorted((p for p in parent.iterdir() if p.is_dir()), key=lambda p: p.stat().st_mtime,
                     reverse=True)
    for old in folders[KEEP:]:
        shutil.rmtree(old, ignore_errors=True)
