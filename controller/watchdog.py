"""Input checks and the measurement watchdog of the loop.

A measurement or reference is accepted only if it is a finite number in its
range; anything else is counted as a fault and never reaches the command.
The watchdog is the fast path of the safety design (DESIGN.md, Zenoh): no
fresh measurement for ``stale_ms`` puts the loop in the safe state, and only
fresh data brings it back. Liveliness tokens are the slow backup.
"""
from __future__ import annotations

import math

STATES = ("running", "safe", "fault")
RUNNING, SAFE, FAULT = range(3)


def in_range(lo: float, hi: float):
    """A check ``accept(v) -> bool``: a finite float within [lo, hi]."""

    def accept(v) -> bool:
        return isinstance(v, float) and math.isfinite(v) and lo <= v <= hi

    return accept


class Faults:
    """Fault kinds with the time of the first occurrence and a count (the summary's ``faults``).

    ``changes`` counts the calls that changed a count: a reader that keeps :meth:`counts` takes them anew only
    when it moved (the loop's status).
    """

    def __init__(self):
        self._first: dict[str, float] = {}
        self._count: dict[str, int] = {}
        self.changes = 0

    def add(self, kind: str, t_s: float, n: int = 1) -> None:
        if n <= 0:
            return
        self.changes += 1
        if kind not in self._first:
            self._first[kind] = t_s
            self._count[kind] = 0
        self._count[kind] += n

    def add_rejects(self, rejects, t_s: float, kind: str) -> None:
        """Count a transport's rejects: ``n`` of ``kind``, or a mapping ``{kind: n}`` of several kinds."""
        if isinstance(rejects, dict):
            for k, n in rejects.items():
                self.add(k, t_s, n)
        else:
            self.add(kind, t_s, rejects)

    def counts(self) -> dict[str, int]:
        return dict(self._count)

    def to_list(self) -> list[dict]:
        return [{"kind": k, "first_s": self._first[k], "count": self._count[k]} for k in self._first]


class Watchdog:
    """Age of the latest fresh input, and whether it is stale.

    Parameters
    ----------
    stale_s : float
        Age above which the input is stale, s.
    t0_s : float
        Start time: an input never seen is as old as the run.
    """

    def __init__(self, stale_s: float, t0_s: float):
        self.stale_s = stale_s
        self.last_s = t0_s

    def fresh(self, t_s: float) -> None:
        self.last_s = t_s

    def age(self, t_s: float) -> float:
        return t_s - self.last_s

    def stale(self, t_s: float) -> bool:
        return t_s - self.last_s > self.stale_s
