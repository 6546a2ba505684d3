"""What a plain deployment (no certificates) can do against a second publisher of a key.

Without TLS anyone who reaches the endpoint can put ``meas/flow``. The guard
believes one publisher per key: the first one heard, named by its ``src``
field (the valve node puts its Zenoh session id there; a publisher without
one is the anonymous source ``None``) and followed by its ``seq``, which must
increase. A sample from another source, or one whose ``seq`` does not
increase (a replay, or a forger interleaving with the real publisher), is
rejected and counted (``spoofed_measurement`` for ``meas/flow``): it never
refreshes the stale watchdog, so a third process publishing ``meas/flow = 0``
cannot hide a dead valve node, and cannot steer the loop while the real one
lives.

A publisher that restarts comes back as a new source (or, anonymous, with
its ``seq`` from 0 again); it is believed once the old one has been silent
for ``release_s`` (the loop's ``stale_ms``: the
loop has gone safe by then), unless a second source was seen while the first
was alive (``contested``): then the guard keeps the lock, the loop stays
safe, and only a restart of the controller (an operator's decision) clears
it. A forger that copies ``src`` and keeps its ``seq`` ahead of the real
one's is still flagged (the real samples then run backwards) but believed:
only the secure configuration (``--certs``) keeps it out.
"""
from __future__ import annotations

import time

_NOBODY = object()


class SourceGuard:
    """Believe one publisher of a key; see the module docstring.

    Parameters
    ----------
    release_s : float
        Silence of the believed source after which a new source may take over, s.
    clock : callable
        Monotonic time, s.
    """

    def __init__(self, release_s: float, clock=time.monotonic):
        self.release_s = release_s
        self.clock = clock
        self.src = _NOBODY
        self.seq: int | None = None
        self.last_s = 0.0
        self.contested = False

    def believe(self, src: str | None, seq: int | None) -> bool:
        """True to believe a well-formed sample from ``src`` numbered ``seq``; False flags it."""
        now = self.clock()
        if self.src is _NOBODY or (not self.contested and now - self.last_s > self.release_s):
            self.src, self.seq = src, None  # the first source, or a restart after the old one fell silent
        elif src != self.src or (self.seq is not None and (seq is None or seq <= self.seq)):
            self.contested = True
            return False
        self.seq, self.last_s = seq, now
        return True
