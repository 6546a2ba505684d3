"""Write a file so that readers see the old content or the new, never a part, and a kill leaves nothing behind.

The new content goes to an anonymous file in the target's folder
(``O_TMPFILE``: it has no name, so a process killed while writing, even by
SIGKILL, leaves no temporary file); once complete and fsynced it gets a
temporary name (``linkat`` through ``/proc/self/fd``) and is renamed over
the target in the same instant. Only a kill in the microseconds between
those two calls can leave a named temporary, ``.NAME.tmpPID``; the next
write to the same target removes any such file whose process is gone.
Where ``O_TMPFILE`` is missing (not Linux, or a filesystem without it) the
content is written under the temporary name from the start, removed on any
exception, and swept the same way after a kill.
"""
from __future__ import annotations

import contextlib
import glob
import os
import re


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale(path: str) -> None:
    """Remove the temporaries ``.NAME.tmpPID`` beside ``path`` left by processes that are gone."""
    folder, base = os.path.split(os.path.abspath(path))
    for tmp in glob.glob(os.path.join(glob.escape(folder), f".{glob.escape(base)}.tmp*")):
        m = re.fullmatch(r"\.tmp(\d+)", os.path.basename(tmp)[len(base) + 1:])
        if m and int(m.group(1)) != os.getpid() and not _pid_alive(int(m.group(1))):
            with contextlib.suppress(OSError):
                os.remove(tmp)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", encoding: str | None = "utf-8", newline: str | None = None):
    """``with atomic_open(path) as fh: fh.write(...)``: ``path`` is replaced when the block ends without error.

    Parameters
    ----------
    path : str or path-like
        The target; its folder must exist.
    mode : {"w", "wb"}
    encoding, newline : as :func:`open` (text mode only).
    """
    path = os.path.abspath(os.fspath(path))
    if os.path.exists(path) and not os.path.isfile(path):  # renaming over it would replace /dev/null itself
        from .recording import InputError

        raise InputError(f"{path}: exists and is not a regular file (a folder, device, FIFO or socket)")
    folder, base = os.path.split(path)
    tmp = os.path.join(folder, f".{base}.tmp{os.getpid()}")
    sweep_stale(path)
    text = "b" not in mode
    kw = {"encoding": encoding, "newline": newline} if text else {}
    try:
        fd = os.open(folder, os.O_TMPFILE | os.O_RDWR, 0o666)
        named = False
    except (AttributeError, OSError):  # no O_TMPFILE here: a named temporary from the start
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
        named = True
    try:
        with os.fdopen(fd, "w" if text else "wb", **kw) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
            if not named:
                _name(fh.fileno(), folder, tmp)
                named = True
        os.replace(tmp, path)
    except BaseException:
        if named:
            with contextlib.suppress(OSError):
                os.remove(tmp)
        raise


def _name(fd: int, folder: str, tmp: str) -> None:
    """Give the anonymous file ``fd`` the name ``tmp`` (``linkat`` following ``/proc/self/fd``),
    or, where that is refused, copy its content to ``tmp``."""
    with contextlib.suppress(FileNotFoundError):
        os.remove(tmp)
    dfd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:  # a dir fd makes os.link call linkat, which follows the /proc link to the open file
        os.link(f"/proc/self/fd/{fd}", os.path.basename(tmp), dst_dir_fd=dfd, follow_symlinks=True)
        return
    except OSError:
        pass
    finally:
        os.close(dfd)
    out = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        while chunk := os.read(fd, 1 << 20):
            os.write(out, chunk)
        os.fsync(out)
    finally:
        os.close(out)


def write_text_atomic(path: str | os.PathLike, text: str, newline: str | None = None) -> None:
    """Replace ``path`` by ``text`` (UTF-8) through :func:`atomic_open`."""
    with atomic_open(path, newline=newline) as fh:
        fh.write(text)


def save_figure_atomic(fig, path: str | os.PathLike, **savefig_kw) -> None:
    """``fig.savefig`` to ``path`` through :func:`atomic_open` (the format from the file's suffix, PNG without one)."""
    fmt = os.path.splitext(os.fspath(path))[1].lstrip(".").lower() or "png"
    with atomic_open(path, "wb") as fh:
        fig.savefig(fh, format=fmt, **savefig_kw)
