"""Output paths checked before the work that fills them: a bad path is bad input now, not a traceback later."""
from __future__ import annotations

import errno
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
        if path is None:
            continue
        flag = _flag(name)
        check_output_file(path, flag)
        if name == "plot":  # matplotlib picks the format by the suffix: an unknown one fails after the work
            from matplotlib.backend_bases import FigureCanvasBase

            formats = FigureCanvasBase.get_supported_filetypes()
            suffix = os.path.splitext(path)[1].lstrip(".").lower()
            if suffix not in formats:
                raise InputError(f"--plot {path}: the file name must end in one of "
                                 f"{', '.join('.' + f for f in sorted(formats))}")
    for name in folders:
        path = getattr(args, name, None)
        if path is None:
            continue
        if not path:
            raise InputError(f"--{name}: an empty path")
        try:
            os.makedirs(path, exist_ok=True)
        except OSError as exc:
            raise InputError(f"--{name} {path}: cannot create the folder ({exc.strerror})") from None
        _probe(path, f"--{name} {path}: folder")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _probe(folder: str, what: str) -> None:
    """Create and remove a file in ``folder``: the only sure test that outputs can be written there (root
    passes every permission check, yet ``/proc`` or a read-only mount refuses the file)."""
    try:
        fd = os.open(folder, os.O_TMPFILE | os.O_WRONLY, 0o600)  # no name: nothing left behind if killed
    except (AttributeError, OSError) as exc:
        if getattr(exc, "errno", None) not in (None, errno.EOPNOTSUPP, errno.EISDIR, errno.EINVAL):
            raise InputError(f"{what} is not writable ({exc.strerror})") from None
        probe = os.path.join(folder, f".valvectl-probe-{os.getpid()}")
        try:
            fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except OSError as exc:
            raise InputError(f"{what} is not writable ({exc.strerror})") from None
        os.unlink(probe)
    os.close(fd)


def check_output_file(path: str, flag: str) -> None:
    """One output file can be written: a non-empty path, not a folder, not a special file (writing there
    would replace ``/dev/null`` with a file, or block on a FIFO), a name the file system takes, in an
    existing writable folder. Raises :class:`InputError` naming ``flag`` and the path."""
    if not path:
        raise InputError(f"{flag}: an empty path")
    if path.endswith(("/", os.sep)) or os.path.isdir(path):
        raise InputError(f"{flag} {path}: is a folder, not a file")
    if os.path.exists(path) and not os.path.isfile(path):
        raise InputError(f"{flag} {path}: exists and is not a regular file (a device, FIFO or socket)")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise InputError(f"{flag} {path}: folder {parent} does not exist")
    base = os.path.basename(path)
    try:
        limit = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        limit = 255
    if len(base.encode("utf-8", "surrogateescape")) > limit:
        raise InputError(f"{flag} {path[:80]}...: file name longer than {limit} bytes")
    _probe(parent, f"{flag} {path}: folder {parent}")
