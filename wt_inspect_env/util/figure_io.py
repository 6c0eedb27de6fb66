"""Writing matplotlib figures: the formats every command offers and one atomic save.

Every command that draws (``plan``, ``evaluate``, ``train``) takes ``--figure-format png|pdf|svg``;
the set of formats and the way a figure reaches the disk live here, once, so a new format or a
change of resolution applies to all of them. PNG is for screens and the README; PDF and SVG are
vector formats for papers (text stays text, lines stay sharp at any zoom).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .atomic_io import atomic_path
from .validation import check_choice

FIGURE_FORMATS: tuple[str, ...] = ("png", "pdf", "svg")
DEFAULT_FIGURE_FORMAT = "png"
# Raster resolution of PNG figures (vector formats ignore it except for rasterised artists): high
# enough that 8-pt labels stay legible when a figure is shown at full width.
PNG_DPI = 150


def check_figure_format(fmt: Any) -> str:
    """``fmt`` if it is one of :data:`FIGURE_FORMATS` (ValueError naming the valid ones otherwise)."""
    return check_choice("figure_format", fmt, FIGURE_FORMATS)


def save_figure(fig: Any, path: str | Path, fmt: str = DEFAULT_FIGURE_FORMAT, *, dpi: int = PNG_DPI,
                **savefig_kwargs: Any) -> Path:
    """Write ``fig`` to ``path`` with its suffix replaced by ``.fmt``, atomically (a reader never sees
    a half-written figure). Returns the written path. ``savefig_kwargs`` go to ``Figure.savefig``."""
    fmt = check_figure_format(fmt)
    target = Path(path).with_suffix("." + fmt)
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format=fmt, dpi=dpi, **savefig_kwargs)
    return target


def save_and_close(fig: Any, path: str | Path, fmt: str = DEFAULT_FIGURE_FORMAT, **savefig_kwargs: Any) -> Path:
    """:func:`save_figure`, then free the figure whether or not the write succeeded: pyplot keeps
    every open figure alive, so a command drawing many would otherwise grow until it exits."""
    import matplotlib.pyplot as plt
    try:
        return save_figure(fig, path, fmt, **savefig_kwargs)
    finally:
        plt.close(fig)


__all__ = ["FIGURE_FORMATS", "DEFAULT_FIGURE_FORMAT", "PNG_DPI", "check_figure_format", "save_figure",
           "save_and_close"]
