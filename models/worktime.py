"""Seconds of work alone: wall time minus the time numba spent compiling or loading kernels.

The ``*_s`` figures (``fit_s``, a sweep's ``seconds``) say how long the work
takes, the same on the first run after install as on the hundredth: numba
compiles a kernel on its first call and loads it from its cache on the first
call of later processes (milliseconds to seconds each), and that time is
left out. Numba holds its compiler lock for both, and announces the lock
with the ``numba:compiler_lock`` event, which :class:`WorkTimer` listens to
(nested holds counted once). Imports are left out by importing before the
timer starts.
"""
from __future__ import annotations

import time


class WorkTimer:
    """Context manager: ``seconds`` of wall time inside it, less numba's compiling and cache loading.

    Examples
    --------
    >>> with WorkTimer() as t:
    ...     pass
    >>> t.seconds >= 0.0
    True
    """

    def __enter__(self) -> "WorkTimer":
        from numba.core import event

        self._listener = event.TimingListener()
        self._scope = event.install_listener("numba:compiler_lock", self._listener)
        self._scope.__enter__()
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        wall = time.perf_counter() - self._t0
        self._scope.__exit__(*exc)
        #: Time numba held its compiler lock (compiling, loading from its cache), s.
        self.compile_s = self._listener.duration if self._listener.done else 0.0
        #: The work alone, s.
        self.seconds = max(wall - self.compile_s, 0.0)
