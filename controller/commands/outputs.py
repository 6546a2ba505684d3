"""Output paths checked before the work that fills them: a bad path is bad input now, not a traceback later."""
from __future__ import annotations

import os

from models.recording import InputError


def check_outputs(args, files=("json", "plot", "record"), folders=("report",)) -> None:
    """Each given output of ``args`` (``--json``, ``--plot``, ``--record``: files; ``--report``: a folder)
    can be written: its folder exists and is writable (a report folder is created), and a plot's suffix names
    a format matplotlib writes.

    Raises
    ------
    InputError
        One line naming the flag, the path and the problem.
    """
    for name in files:
        path = getattr(args, name, None)
        if not path:
            continue
        parent = os.path.dirname(os.path.abspath(path))
        if os.path.isdir(path):
            raise InputError(f"--{name} {path}: is a folder, not a file")
        if not os.path.isdir(parent):
            raise InputError(f"--{name} {path}: folder {parent} does not exist")
        if not os.access(parent, os.W_OK):
            raise InputError(f"--{name} {path}: folder {parent} is not writable")
        if name == "plot":  # matplotlib picks the format by the suffix: an unknown one fails after the work
            from matplotlib.backend_bases import FigureCanvasBase

            formats = FigureCanvasBase.get_supported_filetypes()
            suffix = os.path.splitext(path)[1].lstrip(".").lower()
            if suffix not in formats:
                raise InputError(f"--plot {path}: the file name must end in one of "
                                 f"{', '.join('.' + f for f in sorted(formats))}")
    for name in folders:
        path = getattr(args, name, None)
        if not path:
            continue
        try:
            os.makedirs(path, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--{name} {path}: cannot create the folder ({exc.strerror})") from None
        if not os.access(path, os.W_OK):
            raise InputError(f"--{name} {path}: folder is not writable")
