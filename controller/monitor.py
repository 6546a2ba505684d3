"""The live view of a controller running in another process: what ``ctrl/status`` says, at its rate.

:class:`MonitorState` keeps the newest status and a rolling window of the
reference, flow, error and duty; :func:`render` draws it with rich (state,
controller, the signals with sparklines over the window, loop timing,
faults and alarms); :data:`MONITOR_COLUMNS` is the ``--record`` file's row.
Nothing here talks to Zenoh: the verb (:mod:`controller.commands.monitor`)
feeds statuses in, so the view is tested on plain dicts.
"""
from __future__ import annotations

import math
import re
from collections import deque

from controller.transport.payload import Message, PayloadError, decode

#: The monitor recording (DESIGN.md): one row per ``ctrl/status`` received.
MONITOR_COLUMNS = ("t_s", "state", "controller", "ref_lpm", "flow_lpm", "duty_pct", "error_lpm", "alarms")
#: Sparkline glyphs, lowest to highest.
BARS = "▁▂▃▄▅▆▇█"


def parse_status(data: bytes) -> Message:
    """A ``ctrl/status`` payload: ``value`` is an object (state, controller, signals, timing, faults, alarms)."""
    obj = decode(data)
    v = obj.get("value")
    if not isinstance(v, dict) or not isinstance(v.get("state"), str):
        raise PayloadError("value is not a status object")
    seq, t = obj.get("seq"), obj.get("t")
    return Message(v, seq if type(seq) is int else None, _num(t) if t is not None else None, None)


def _num(v) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan


def _cell(v) -> str:
    """A text cell of the monitor recording: what a status says, cut to 64 characters, with no comma, quote or
    line break (a status of the network must not add columns or rows to the CSV)."""
    return re.sub(r'[,"\r\n]', " ", str(v))[:64]


def sparkline(values, width: int) -> str:
    """The last ``width`` values as block glyphs scaled between their min and max (nan: a space)."""
    vals = list(values)[-width:]
    finite = [v for v in vals if v == v]
    if not finite:
        return " " * len(vals)
    lo, hi = min(finite), max(finite)
    # scaled in halves: hi - lo and v - lo overflow to inf for values near +-1e308 (inf / inf is nan)
    span = hi / 2 - lo / 2
    out = []
    for v in vals:
        if v != v:
            out.append(" ")
        else:
            out.append(BARS[0] if span <= 0 else BARS[min(len(BARS) - 1, int((v / 2 - lo / 2) / span * len(BARS)))])
    return "".join(out)


class MonitorState:
    """The newest status and a rolling window of the signals.

    Parameters
    ----------
    window : int
        Statuses kept for the sparklines (at 10 Hz, 100 = the last 10 s).
    """

    SIGNALS = ("ref_lpm", "flow_lpm", "error_lpm", "duty_pct")

    def __init__(self, window: int = 100):
        self.status: dict | None = None
        self.t_s = math.nan
        self.received = 0
        self.bad = 0
        self.history = {k: deque(maxlen=window) for k in self.SIGNALS}

    def add(self, t_s: float | None, status: dict) -> tuple:
        """Take one status (``t_s``: the controller's time); returns its :data:`MONITOR_COLUMNS` row."""
        self.status, self.received = status, self.received + 1
        self.t_s = _num(t_s)
        for k in self.SIGNALS:
            self.history[k].append(_num(status.get(k)))
        alarms = status.get("alarms")
        alarms = ";".join(a for a in alarms if isinstance(a, str)) if isinstance(alarms, list) else ""
        return (self.t_s, _cell(status.get("state")), _cell(status.get("controller", "")),
                *(self.history[k][-1] for k in ("ref_lpm", "flow_lpm", "duty_pct", "error_lpm")), _cell(alarms))


_STATE_STYLE = {"running": "bold green", "safe": "bold yellow", "fault": "bold red"}


def render(m: MonitorState, source: str, age_s: float | None = None, width: int = 60):
    """The view as a rich renderable: a header line, the signals table and the events."""
    from rich.console import Group
    from rich.panel import Panel
    from rich.table import Table
    from rich.text import Text

    st = m.status
    head = Text(f"valvectl monitor  {source}  ")
    if st is None:
        head.append("waiting for ctrl/status...", style="dim")
        return Panel(head, title="valvectl monitor")
    head.append(f"{st.get('state', '?')}", style=_STATE_STYLE.get(st.get("state"), "bold"))
    head.append(f"  controller {st.get('controller', '?')}", style="bold cyan")
    head.append(f"  t {m.t_s:.1f} s  statuses {m.received}")
    if age_s is not None and age_s > 1.0:
        head.append(f"  no status for {age_s:.1f} s", style="bold red")
    sig = Table(box=None, pad_edge=False, expand=False)
    sig.add_column("signal")
    sig.add_column("now", justify="right")
    sig.add_column("min", justify="right")
    sig.add_column("max", justify="right")
    sig.add_column(f"last {len(m.history['flow_lpm'])} statuses")
    names = {"ref_lpm": "reference L/min", "flow_lpm": "flow L/min", "error_lpm": "error L/min", "duty_pct": "duty %"}
    for k, label in names.items():
        h = [v for v in m.history[k] if v == v]
        now = m.history[k][-1] if m.history[k] else math.nan
        sig.add_row(label, f"{now:8.2f}", f"{min(h):8.2f}" if h else "-", f"{max(h):8.2f}" if h else "-",
                    Text(sparkline(m.history[k], width), style="cyan"))
    timing = Text(f"loop: steps {st.get('steps', '-')}  overruns {st.get('overruns', '-')}  "
                  f"lateness max {_num(st.get('lateness_us_max')):.0f} us  "
                  f"compute max {_num(st.get('compute_us_max')):.0f} us  IAE {_num(st.get('iae')):.4f} L")
    faults = st.get("faults") if isinstance(st.get("faults"), dict) else {}
    ftext = Text("faults: ")
    ftext.append(", ".join(f"{k} x{v}" for k, v in faults.items()) or "none", style="yellow" if faults else "green")
    active = st.get("alarms") if isinstance(st.get("alarms"), list) else []
    counts = st.get("alarm_counts") if isinstance(st.get("alarm_counts"), dict) else {}
    atext = Text("alarms: ")
    if active:
        atext.append("ACTIVE " + ", ".join(map(str, active)), style="bold white on red")
        atext.append("  ")
    atext.append(", ".join(f"{k} x{v}" for k, v in counts.items()) or ("" if active else "none"),
                 style="red" if counts else "green")
    return Panel(Group(head, sig, timing, ftext, atext), title="valvectl monitor", expand=False)
