"""Figures say how they were made in a header that fits, whatever the command's length."""

import numpy as np

from camwhisker.files.figures import new_figure, save_figure


def _texts_inside(fig) -> list[str]:
    """The figure's texts, titles, axis labels and x tick labels that run past its edges."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    width, height = fig.bbox.width, fig.bbox.height
    texts = list(fig.texts)
    for ax in fig.axes:
        texts += [ax.title, ax.xaxis.label, ax.yaxis.label]
        lo, hi = sorted(ax.get_xlim())
        texts += [t for t in ax.get_xticklabels() if lo <= t.get_position()[0] <= hi]
    out = []
    for t in texts:
        if not t.get_text().strip():
            continue
        b = t.get_window_extent(renderer)
        # One pixel of slack: antialiasing rounds extents outward.
        if b.x0 < -1 or b.y0 < -1 or b.x1 > width + 1 or b.y1 > height + 1:
            out.append(t.get_text()[:40])
    return out


def test_a_long_command_wraps_inside_the_figure(tmp_path):
    fig, ax = new_figure((4.0, 3.0))
    ax.plot(np.arange(5.0))
    how = "camwhisker calibrate-sensor " + " ".join(f"/data/bench/run{i}/sweep.avi"
                                                     for i in range(12))
    save_figure(fig, tmp_path / "f.png", how)
    assert _texts_inside(fig) == []
    header = fig.texts[-1].get_text()
    # All of it is there (12 paths), over several lines of at most the figure's width.
    assert header.replace("\n", " ").endswith("run11/sweep.avi") and header.count("\n") >= 3
    assert (tmp_path / "f.png").stat().st_size > 0
