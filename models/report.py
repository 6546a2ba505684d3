"""Markdown reports with PNG figures, the form every verb's ``--report DIR`` takes.

A report is a folder: ``report.md`` (written last, atomically, so a reader
never sees one that names a missing figure) and one PNG per figure.
"""
from __future__ import annotations

from pathlib import Path

from .atomicfile import save_figure_atomic, write_text_atomic


def write_report(folder, title: str, blocks, figures: dict | None = None, dpi: int = 110) -> Path:
    """Write ``folder/report.md`` and the figures; returns the Markdown file's path.

    Parameters
    ----------
    folder : path-like
        Created if missing.
    title : str
        The report's heading.
    blocks : sequence of str
        Markdown paragraphs, tables or code blocks, in order; ``{fig:NAME}`` in
        a block is replaced by the image of figure ``NAME``.
    figures : dict of str to matplotlib.figure.Figure
        Saved as ``NAME.png``; figures no block names are shown at the end.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    figures = figures or {}
    for name, fig in figures.items():
        save_figure_atomic(fig, folder / f"{name}.png", dpi=dpi)
    text = "\n\n".join(blocks)
    for name in figures:
        tag = "{fig:" + name + "}"
        if tag in text:
            text = text.replace(tag, f"![{name}]({name}.png)")
        else:
            text += f"\n\n![{name}]({name}.png)"
    path = folder / "report.md"
    write_text_atomic(path, f"# {title}\n\n{text}\n")
    return path
