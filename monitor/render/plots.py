"""Plots for the report (matplotlib, Agg, offscreen): a section through a finding and
removal and feed over machine time. Each returns an RGB uint8 image."""

from __future__ import annotations

import numpy as np


def _figure(width_px: int, height_px: int):
    import matplotlib

    matplotlib.use("Agg", force=False)
    from matplotlib.figure import Figure

    dpi = 100
    fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
    return fig


def _image(fig) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def section_plot(x: np.ndarray, model: np.ndarray, design: np.ndarray | None, stock: np.ndarray | None,
                 at: float, title: str, axis: str = "X", size=(560, 300)) -> np.ndarray:
    """A vertical section: heights (mm) of the ``model`` at the stage, the ``design`` and
    the uncut ``stock`` along ``x`` (mm, the ``axis`` through the finding), gouges (model
    below design) filled red and excess (above) blue, the finding at ``at`` marked."""
    fig = _figure(*size)
    ax = fig.add_subplot(1, 1, 1)
    if stock is not None and np.isfinite(stock).any():
        ax.plot(x, stock, color="#999999", lw=1, ls=":", label="stock")
    ax.plot(x, model, color="#222222", lw=1.6, label="model at this stage")
    if design is not None and np.isfinite(design).any():
        ax.plot(x, design, color="#2a9d3a", lw=1.2, ls="--", label="design")
        with np.errstate(invalid="ignore"):
            ax.fill_between(x, model, design, where=model < design, color="#d00000", alpha=0.6, label="gouge")
            ax.fill_between(x, model, design, where=model > design, color="#3060d0", alpha=0.25,
                            label="material left")
    ax.axvline(at, color="#d00000", lw=1, alpha=0.7)
    # the Z range of the model and the design here (the stock far above stays off it)
    # (without a design the stock is the reference: kept in the range)
    near = np.concatenate([v[np.isfinite(v)] for v in (model, design if design is not None else stock)
                           if v is not None])
    if near.size:
        lo, hi = float(near.min()), float(near.max())
        pad = max(0.25 * (hi - lo), 0.3)
        ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlabel(f"{axis} (mm)")
    ax.set_ylabel("Z (mm)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return _image(fig)


def timeline_plot(t_removal: np.ndarray, removal_rate: np.ndarray, t_feed: np.ndarray, feed: np.ndarray,
                  findings_t: list[tuple[float, str]] = (), size=(900, 320)) -> np.ndarray:
    """Removal rate (mm^3/s) and programmed feed (mm/min) over machine time (s), the
    findings marked at their times."""
    fig = _figure(*size)
    ax = fig.add_subplot(1, 1, 1)
    if len(t_removal):
        ax.fill_between(t_removal, removal_rate, step="post", color="#4477aa", alpha=0.5)
        ax.step(t_removal, removal_rate, where="post", color="#4477aa", lw=1, label="removal (mm³/s)")
    ax.set_xlabel("machine time (s)")
    ax.set_ylabel("removal (mm³/s)", color="#4477aa")
    ax2 = ax.twinx()
    if len(t_feed):
        ax2.step(t_feed, feed, where="post", color="#dd7700", lw=1.2, label="feed (mm/min)")
    ax2.set_ylabel("feed (mm/min)", color="#dd7700")
    for t, label in findings_t:
        ax.axvline(t, color="#d00000", lw=1, alpha=0.8)
        ax.text(t, ax.get_ylim()[1], label, color="#d00000", fontsize=8, rotation=90, va="top", ha="right")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return _image(fig)
