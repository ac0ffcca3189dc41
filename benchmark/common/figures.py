"""Writing a matplotlib figure the one way every report does."""

from __future__ import annotations

from pathlib import Path


def save_figure(fig, path: Path, dpi: int = 110, tight: bool = True) -> Path:
    """Lay the figure out (unless `tight` is off), write it to `path` (folders made), close it; returns `path`."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
