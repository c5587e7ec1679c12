"""Figures as PNG files: made without pyplot, so no backend is chosen for the caller.

A notebook that imports the package keeps its own matplotlib backend; these figures
render through Agg when saved, whatever the backend is.
"""

from __future__ import annotations

import io
import textwrap

from matplotlib.figure import Figure

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_bytes

__all__ = ["new_figure", "save_figure", "HEADER_HEIGHT"]

#: Share of the figure's height kept above the axes for the provenance line.
HEADER_HEIGHT = 0.035
# The provenance line's font (points) and the characters of it an inch holds (6 pt text
# runs about 3.3 pt per character).
_HEADER_PT = 6
_CHARS_PER_INCH = 72 / 3.3


def new_figure(figsize: tuple[float, float], **subplots):
    """A figure with constrained layout and its axes (``Figure.subplots(**subplots)``)."""
    fig = Figure(figsize=figsize, layout="constrained")
    return fig, fig.subplots(**subplots)


def save_figure(fig: Figure, path, how: str) -> None:
    """Write ``fig`` as a PNG at ``path`` (atomically) under a line saying ``how`` it was made."""
    # The panels (constrained layout, legends below them included) end under a strip
    # that says how the figure was made, wrapped to the figure's width.
    width_in, height_in = fig.get_size_inches()
    lines = textwrap.wrap(f"camwhisker {__version__}: {how}",
                          max(20, int(0.98 * width_in * _CHARS_PER_INCH)))
    header = max(HEADER_HEIGHT, len(lines) * 1.3 * _HEADER_PT / 72 / height_in + 0.01)
    fig.get_layout_engine().set(rect=(0, 0, 1, 1 - header))
    fig.text(0.01, 0.995, "\n".join(lines), fontsize=_HEADER_PT, color="0.4", va="top")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120,
                metadata={"Software": f"camwhisker {__version__}", "Description": how})
    atomic_write_bytes(path, buf.getvalue())
