"""Writing a matplotlib figure to a file: one line when the file cannot be written."""

from __future__ import annotations

from typing import TYPE_CHECKING

from dockhil.errors import DockhilError

if TYPE_CHECKING:
    from os import PathLike

    from matplotlib.figure import Figure


def save_figure(fig: Figure, path: str | PathLike[str], dpi: int = 110) -> None:
    """fig.savefig(path), then close the figure; a place that cannot be written is one DockhilError line."""
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise DockhilError(f"--png {path}: cannot write the figure ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)
