"""Figures for the controllers' reports (training curves, the control comparison)."""
from __future__ import annotations

from typing import Any


def new_figure(**kwargs: Any) -> Any:
    """A matplotlib ``Figure`` (``kwargs``: its arguments) on its own Agg canvas, apart from
    pyplot: drawing it neither switches the user's backend nor opens a window, and it is
    freed with its last reference."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig
