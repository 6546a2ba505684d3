"""Where the chunks of a sweep run: a local process pool, or a Dask distributed cluster.

A chunk is a picklable task (a top-level function and its argument) that
simulates a block of candidates; :func:`map_chunks` returns the results in
chunk order whatever order they finish in, so the table does not depend on
where the chunks ran. With ``scheduler`` (a Dask scheduler address such as
``tcp://10.0.0.5:8786``, or the address of an in-process ``LocalCluster``) the
chunks go to that cluster's workers, which must be able to import this
package; without it they go to a local pool of ``workers`` processes (one per
core by default; 1 runs them in this process).
"""
from __future__ import annotations

import os
import sys
from typing import Callable, Sequence

from models.recording import InputError


def default_workers() -> int:
    """One worker per core this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def _progress(total: int, desc: str):
    from tqdm import tqdm

    # tqdm shows itself only when stderr is a terminal (disable=None)
    return tqdm(total=total, desc=desc, unit="cand", file=sys.stderr, disable=None, smoothing=0.1, leave=False)


def map_chunks(fn: Callable, chunks: Sequence, sizes: Sequence[int], scheduler: str | None = None,
               workers: int | None = None, desc: str = "sweep") -> list:
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
    """
    with _progress(sum(sizes), desc) as bar:
        if scheduler:
            return _dask(fn, chunks, sizes, scheduler, bar)
        n = workers or default_workers()
        if n <= 1 or len(chunks) <= 1:
            out = []
            for c, s in zip(chunks, sizes):
                out.append(fn(c))
                bar.update(s)
            return out
        return _pool(fn, chunks, sizes, n, bar)


def _pool(fn, chunks, sizes, n, bar) -> list:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # fork: workers inherit the imported modules and numba's compiled kernels
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    out = [None] * len(chunks)
    with ProcessPoolExecutor(max_workers=min(n, len(chunks)), mp_context=ctx) as ex:
        futs = {ex.submit(fn, c): i for i, c in enumerate(chunks)}
        for f in as_completed(futs):
            i = futs[f]
            out[i] = f.result()
            bar.update(sizes[i])
    return out


def _dask(fn, chunks, sizes, scheduler, bar) -> list:
    from distributed import Client, as_completed

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None
    try:
        futs = client.map(fn, list(chunks), pure=False)
        index = {f.key: i for i, f in enumerate(futs)}
        out = [None] * len(chunks)
        for f in as_completed(futs):
            i = index[f.key]
            out[i] = f.result()
            bar.update(sizes[i])
        return out
    finally:
        client.close()
