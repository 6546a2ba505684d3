"""Where the chunks of a sweep run: a local process pool, or a Dask distributed cluster.

A chunk is a picklable task (a top-level function and its argument) that
simulates a block of candidates; :func:`map_chunks` returns the results in
chunk order whatever order they finish in, so the table does not depend on
where the chunks ran. With ``scheduler`` (a Dask scheduler address such as
``tcp://10.0.0.5:8786``, or the address of an in-process ``LocalCluster``) the
chunks go to that cluster's workers, which must be able to import this
package; without it they go to a local pool of ``workers`` processes (one per
core by default; 1 runs them in this process).

Local workers die with the sweep, however it ends: each asks the kernel
for ``SIGKILL`` when its parent exits (``prctl(PR_SET_PDEATHSIG)``, Linux;
elsewhere a thread watching the parent's pid), so a sweep killed with
SIGTERM or SIGKILL leaves no process burning the cores a control loop needs.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from typing import Callable, Sequence

from models.recording import InputError


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


PR_SET_PDEATHSIG = 1  # linux/prctl.h


def die_with_parent(parent_pid: int) -> None:
    """Pool-worker initializer: end this process when ``parent_pid`` ends.

    ``PR_SET_PDEATHSIG`` makes the kernel send SIGKILL at the parent's exit,
    even a SIGKILL of the parent; a parent gone before the call is caught by
    comparing ``getppid()``. Without ``prctl`` a daemon thread polls the
    parent every 0.2 s. The worker also ignores SIGINT: Ctrl-C is the
    parent's to handle.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    armed = False
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            armed = ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:
        os._exit(1)
    if not armed:
        def watch():
            while os.getppid() == parent_pid:
                time.sleep(0.2)
            os._exit(1)

        threading.Thread(target=watch, daemon=True, name="die-with-parent").start()


def _progress(total: int, desc: str):
    from tqdm import tqdm

    # tqdm shows itself only when stderr is a terminal (disable=None)
    return tqdm(total=total, desc=desc, unit="cand", file=sys.stderr, disable=None, smoothing=0.1, leave=False)


def map_chunks(fn: Callable, chunks: Sequence, sizes: Sequence[int], scheduler: str | None = None,
               workers: int | None = None, desc: str = "sweep", during: Callable | None = None,
               pool: "LocalPool | None" = None) -> list:
    """``[fn(c) for c in chunks]``, run in parallel, with a progress bar counting ``sizes``.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable).
    chunks : sequence
        Its arguments, one per chunk.
    sizes : sequence of int
        Candidates per chunk, for the progress bar.
    scheduler : str, optional
        Dask scheduler address; a local process pool if absent.
    workers : int, optional
        Local pool size (default: one per core).
    during : callable, optional
        Called once in this process while the chunks run (after they are all submitted).
    pool : LocalPool, optional
        A local pool kept for several calls (forked at its first); else one for this call.
    """
    during = during or (lambda: None)
    with _progress(sum(sizes), desc) as bar:
        if scheduler:
            return _dask(fn, chunks, sizes, scheduler, bar, during)
        n = workers or default_workers()
        if n <= 1 or len(chunks) <= 1:
            during()
            out = []
            for c, s in zip(chunks, sizes):
                out.append(fn(c))
                bar.update(s)
            return out
        if pool is not None:
            return _pool(fn, chunks, sizes, bar, during, pool.executor(n, len(chunks)))
        with LocalPool() as own:
            return _pool(fn, chunks, sizes, bar, during, own.executor(n, len(chunks)))


class LocalPool:
    """A local process pool for several :func:`map_chunks` calls, forked at the first (its workers inherit
    this process's state of that moment: imported modules, numba's loaded kernels, module globals), shut
    down on leaving the ``with`` block."""

    def __init__(self):
        self._ex = None

    def executor(self, n: int, n_chunks: int):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        if self._ex is None:
            ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
            self._ex = ProcessPoolExecutor(max_workers=min(n, n_chunks), mp_context=ctx,
                                           initializer=die_with_parent, initargs=(os.getpid(),))
        return self._ex

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self._ex is not None:
            self._ex.shutdown(wait=True, cancel_futures=True)
            self._ex = None


def _pool(fn, chunks, sizes, bar, during, ex) -> list:
    from concurrent.futures import as_completed

    out = [None] * len(chunks)
    futs = {ex.submit(fn, c): i for i, c in enumerate(chunks)}
    during()
    for f in as_completed(futs):
        i = futs[f]
        out[i] = f.result()
        bar.update(sizes[i])
    return out


def _dask(fn, chunks, sizes, scheduler, bar, during) -> list:
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    try:
        futs = client.map(fn, list(chunks), pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        during()
        out = [None] * len(chunks)
        for f in as_completed(futs):
            i = index[f.key]
            out[i] = f.result()
            bar.update(sizes[i])
        return out
    finally:
        client.close()
