"""Markdown reports with PNG figures, the form every verb's ``--report DIR`` takes.

A report is a folder: ``report.md`` (written last, atomically, so a reader
never sees one that names a missing figure) and one PNG per figure.
"""
from __future__ import annotations

import os
from pathlib import Path


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
        fig.savefig(folder / f"{name}.png", dpi=dpi)
    text = "\n\n".join(blocks)
    for name in figures:
        tag = "{fig:" + name + "}"
        if tag in text:
            text = text.replace(tag, f"![{name}]({name}.png)")
        else:
            text += f"\n\n![{name}]({name}.png)"
    path = folder / "report.md"
    tmp = folder / ".report.md.tmp"
    tmp.write_text(f"# {title}\n\n{text}\n", encoding="utf-8")
    os.replace(tmp, path)
    return path
