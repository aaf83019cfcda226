"""Figures laid out in one measuring pass: room for every axes' labels, titles and legends."""

from __future__ import annotations

import numpy as np

__all__ = ["lay_out", "inside", "PAD_IN"]

#: Space (inches) around each axes' labels, titles and legends, and at the figure's edges.
PAD_IN = 3 / 72


def lay_out(fig, pad_in: float = PAD_IN) -> None:
    """Place the axes of the figure's one grid so that each one's tick labels, axis labels, title and
    legend (also one placed beside the axes) fit in the figure and beside their neighbours.

    Texts on the figure itself (``fig.text``, a title over every panel) are taken to sit at its top:
    the axes start below them. What matplotlib's constrained layout does for the figures of
    :mod:`gonio.report.figures` and :mod:`gonio.plot`, in one measuring pass instead of its two: they are
    drawn in about a third less time. Columns and rows keep the grid's width and height ratios; each gap
    is as wide as the labels on its two sides need. A colour bar is a narrow column of the grid.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    w, h = fig.bbox.width, fig.bbox.height
    pad = pad_in * fig.dpi
    # texts on the figure itself (a title over every panel, placed at the top): their room stays free
    titled = max([h - t.get_window_extent(renderer).y0 for t in fig.texts if t.get_visible()], default=0.0)
    shown = [ax for ax in fig.axes if ax.get_visible() and ax.get_subplotspec() is not None]
    if not shown:
        return
    grid = shown[0].get_subplotspec().get_gridspec()
    rows, cols = grid.get_geometry()
    # what sticks out of each column (left, right) and row (above, below), in pixels
    left, right, above, below = np.zeros(cols), np.zeros(cols), np.zeros(rows), np.zeros(rows)
    for ax in shown:
        spec = ax.get_subplotspec()
        tight, box = ax.get_tightbbox(renderer, for_layout_only=True), ax.get_window_extent(renderer)
        c0, c1, r0, r1 = spec.colspan.start, spec.colspan.stop - 1, spec.rowspan.start, spec.rowspan.stop - 1
        left[c0] = max(left[c0], box.x0 - tight.x0)
        right[c1] = max(right[c1], tight.x1 - box.x1)
        above[r0] = max(above[r0], tight.y1 - box.y1)
        below[r1] = max(below[r1], box.y0 - tight.y0)
    xs = _spans(w, left + pad, right + pad, grid.get_width_ratios() or [1] * cols)
    above[0] += titled
    ys = _spans(h, above + pad, below + pad, grid.get_height_ratios() or [1] * rows)
    for ax in shown:
        spec = ax.get_subplotspec()
        x0, x1 = xs[spec.colspan.start][0], xs[spec.colspan.stop - 1][1]
        top, bottom = ys[spec.rowspan.start][0], ys[spec.rowspan.stop - 1][1]
        ax.set_position([x0 / w, 1 - bottom / h, (x1 - x0) / w, (bottom - top) / h])


def inside(fig) -> bool:
    """Whether every axes' title and axis labels and every figure text lie within the figure (after
    :func:`lay_out`, which leaves out how far a title or an x label wider than its axes reaches: a
    caller saves with ``bbox_inches="tight"`` where one does not fit)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    texts = [*fig.texts]
    for ax in fig.axes:
        if ax.get_visible():
            texts += [ax.title, ax.xaxis.label, ax.yaxis.label]
    edge = fig.bbox.padded(1.0)   # a pixel of rounding
    return all(edge.x0 <= (box := t.get_window_extent(renderer)).x0 and box.x1 <= edge.x1
               and edge.y0 <= box.y0 and box.y1 <= edge.y1 for t in texts if t.get_visible() and t.get_text())


def _spans(size, before, after, ratios) -> list[tuple[float, float]]:
    """(start, end) of each cell along one side of the figure (pixels from its left or top edge): each
    cell has ``before``/``after`` room for what sticks out of it, the rest is shared by ``ratios``."""
    ratios = np.asarray(ratios, np.float64)
    free = max(size - float(np.sum(before) + np.sum(after)), 1.0)
    out, at = [], 0.0
    for k, share in enumerate(ratios / ratios.sum()):
        start = at + before[k]
        at = start + free * share
        out.append((start, at))
        at += after[k]
    return out
