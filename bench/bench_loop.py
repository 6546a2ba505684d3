"""Loop timing at 1 kHz: in-process and over Zenoh, and the Zenoh round trip.

Prints, for the live loop of ``valvectl run`` (ff+kf, config/run.toml):

1. in-process simulated valve, 5 s each: lateness (wake - deadline) and
   compute time per step, for
   a. the naive baseline: ``time.sleep`` to the absolute deadline, normal scheduler;
   b. hybrid sleep-then-spin (``spin_us``), normal scheduler;
   c. hybrid + ``SCHED_FIFO`` (``rt_priority``), the configured default;
   with p99 lateness as a ratio to the baseline's;
   and the step's own work (``compute_us``, the figure of ``make run``) with
   ``make run``'s scheduling: the previous step (pure ``control.step`` on
   fresh one-element arrays, the baseline), today's without the rehearsal
   before each deadline, and today's as ``make run`` runs it, interleaved,
   with the Done-when figures (p50 <= 30 us, p99 <= 60 us);
2. over Zenoh: the controller as its own process (``valvectl run --plant
   zenoh``) and this process as the valve, publishing ``meas/flow`` at 1 kHz
   and busy-polling ``cmd/duty``: the controller's lateness and compute
   (its summary) and the round trip ``meas/flow`` out -> the ``cmd/duty``
   computed from it back (``meas_seq``), as a ratio to the bare Zenoh
   round trip of an echo process (the baseline), for both triggers, with
   the Done-when ratio (trigger measurement p50 <= 1.5x the echo's); and,
   interleaved with them, the fixed-rate controller of an older commit
   (``--baseline``, :data:`BASELINE_COMMIT`, run from a git worktree of it
   with its own config and numba cache), its compute, lateness and
   overruns against this tree's trigger period (Done-when: the fixed-rate
   mode's figures do not get worse).

    .venv/bin/python bench/bench_loop.py [--parts schedulers,compute,zenoh] [--rounds 3] [--baseline COMMIT]

The machine is shared (2 cores, other jobs running): figures vary from run to run. Each case prints the
load average at its start and the hypervisor's steal during it (``/proc/stat``, :func:`bench_load.host_steal_ms`).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import socket
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_load import host_steal_ms  # noqa: E402

from controller.config import controller_params, load_run_config, preview_s  # noqa: E402
from controller.laws import control, kalman  # noqa: E402
from controller.loop import Loop, ProfileReference, RealClock  # noqa: E402
from controller.run_summary import summary  # noqa: E402
from controller.supervisor import Supervisor  # noqa: E402
from controller.transport.sim import SimTransport  # noqa: E402
from controller.watchdog import Faults  # noqa: E402
from models.model import load_model  # noqa: E402
from plant_sim.plant import Plant, load_plant  # noqa: E402
from plant_sim.protocols import BreathProfile  # noqa: E402

SECONDS = 5.0


def pct(x):
    return f"p50 {x['p50']:8.1f}  p99 {x['p99']:8.1f}  max {x['max']:8.0f}"


class PureStepSupervisor(Supervisor):
    """The previous live step (the baseline of compute_us): the pure ``control.step`` per period, fresh
    one-element arrays in and out, the Kalman prediction from ``kalman.predict``."""

    def warm_up(self, dt_s, duty_pct):
        """The live path's warm-up, and this step's too: its kernels (numba's cache, or a compilation) load
        before the first deadline, not in a timed step (the first round once measured a 25 s step)."""
        super().warm_up(dt_s, duty_pct)
        self.step(self.init(0.0, duty_pct), 0.0, 0.0, dt_s, 0.0, 0.0, Faults())
        self._reset()

    def _reset(self):
        super()._reset()
        self._innov_lp, self._model_lag = 0.0, math.nan  # its own health bookkeeping, in Python as it was

    def step(self, ctrl, ref_lpm, meas_lpm, dt_s, ref_ff_lpm, t_s, faults):
        p = self.params
        predicted = float(kalman.predict(p.kf, ctrl.kf)[0]) if p.kf is not None else None
        m = float(kalman.delayed_model(p.kf, ctrl.kf)[0]) if p.kf is not None else None
        new, cmd = control.step(p, ctrl, np.array([ref_lpm]), np.array([meas_lpm]), dt_s, np.array([ref_ff_lpm]))
        if predicted is not None:  # the same health bookkeeping
            g = 1.0 - math.exp(-dt_s / self.settings.tau_s)
            self._innov_lp += (meas_lpm - predicted - self._innov_lp) * g
            a = float(p.kf.a[0])
            lag = m if self._model_lag != self._model_lag else a * self._model_lag + (1.0 - a) * m
            self._model_lag = lag
            self.mismatch_lpm = meas_lpm - lag
        return new, (float(cmd.duty_pct[0]), float(cmd.ff_pct[0]), float(cmd.fb_pct[0]), float(cmd.limit_pct[0]))


class PurePlantTransport(SimTransport):
    """The previous embedded valve (the baseline): the pure ``Plant.step``, a new state each period."""

    def __init__(self, plant):
        super().__init__(plant)
        self._state = plant.init(0.0)

    def command(self, duty_pct, t_s):
        self._state, self.last = self.plant.step(self._state, duty_pct)
        self._meas = self.last.flow_lpm


def conditions(run):
    """``run()``'s result and ``"load L steal S ms"``: the load average at its start, the host's steal during it."""
    load, steal = os.getloadavg()[0], host_steal_ms()
    out = run()
    return out, f"load {load:.1f} steal {host_steal_ms() - steal:.0f} ms"


def in_process(cfg, model, spin_s: float, rt: int, previous: bool = False, rehearse: bool = True) -> dict:
    settings = dataclasses.replace(cfg.loop, spin_s=spin_s, rt_priority=rt, rehearse=rehearse and not previous)
    pp = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
    ref = ProfileReference(BreathProfile(**cfg["profile"]).value, preview_s(cfg, "profile"))
    params = controller_params(cfg, "ff+kf", model)
    if previous:
        sup, valve = PureStepSupervisor({"ff+kf": params}, "ff+kf"), PurePlantTransport(Plant(pp, settings.rate_hz))
    else:
        sup, valve = Supervisor.fixed(params), SimTransport(Plant(pp, settings.rate_hz))
    loop = Loop(sup, valve, ref, settings, clock=RealClock(spin_s))
    return summary(loop.run(SECONDS), "ff+kf", "sim")


#: The baseline peer: answers every meas/flow at once with a cmd/duty naming it, from the subscriber's
#: callback on Zenoh's own thread (no control loop, no polling), its Zenoh threads under the
#: controller's scheduling ([zenoh] io_priority, argv[2]): the bare Zenoh round trip between two
#: Python processes.
ECHO = """
import json, os, sys, time, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"peer"')
c.insert_json5("scouting/multicast/enabled", "false")
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
if int(sys.argv[2]) > 0:
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(sys.argv[2])))
    except PermissionError:
        pass
with zenoh.open(c) as z:
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    pub = z.declare_publisher("vent/valve/insp/cmd/duty", encoding=zenoh.Encoding.APPLICATION_JSON,
                              priority=zenoh.Priority.REAL_TIME, express=True)

    def echo(x):
        d = json.loads(x.payload.to_bytes())
        pub.put(json.dumps({"t": d["t"], "seq": d["seq"], "value": 0.0, "meas_seq": d["seq"]}).encode())

    sub = z.declare_subscriber("vent/valve/insp/meas/flow", echo)
    while True:
        time.sleep(1.0)
"""


ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def baseline_tree(commit: str) -> str:
    """A git worktree of ``commit`` in the temporary folder (made once), its kernels compiled into its own numba
    cache (``controller.precompile``, under SCHED_IDLE) before any timed run."""
    path = os.path.join(tempfile.gettempdir(), f"valvectl-loop-{commit}")
    if not os.path.exists(os.path.join(path, "controller")):
        subprocess.run(["git", "-C", ROOT, "worktree", "add", "--detach", path, commit], check=True,
                       capture_output=True)
    stamp = os.path.join(path, ".precompiled")
    if not os.path.exists(stamp):
        print(f"(compiling {commit}'s kernels in {path}, once)", flush=True)
        subprocess.run(["chrt", "-i", "0", "nice", "-n", "19", sys.executable, "-m", "controller.precompile"],
                       cwd=path, env=tree_env(path), check=True, stdout=subprocess.DEVNULL)
        open(stamp, "w").close()
    return path


def tree_env(tree: str) -> dict:
    """The environment that runs ``tree``'s code with this interpreter (its packages before the installed ones)."""
    return {**os.environ, "PYTHONPATH": tree}


def zenoh_round_trip(cfg, echo: bool = False, trigger: str = "period", tree: str | None = None
                     ) -> tuple[dict | None, np.ndarray]:
    """The valve's view: meas/flow out at 1 kHz, the cmd/duty computed from it back.

    Against the controller (``valvectl run --plant zenoh --trigger TRIGGER``; ``tree``: another
    checkout's, run from there with its own config), or with ``echo`` against :data:`ECHO`.
    """
    import zenoh

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    out = os.path.join(tempfile.mkdtemp(), "s.json")
    if echo:
        ctrl = subprocess.Popen([sys.executable, "-c", ECHO, ep, str(cfg["zenoh"]["io_priority"])])
    else:
        ctrl = subprocess.Popen([sys.executable, "-m", "controller.cli", "run", "--plant", "zenoh", "--listen", ep,
                                 "--duration", "0", "--trigger", trigger, "--json", out], stdout=subprocess.DEVNULL,
                                cwd=tree or ROOT, env=tree_env(tree or ROOT))
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([ep]))
    c.insert_json5("connect/timeout_ms", "-1")
    sent, rtt = {}, []
    with zenoh.open(c) as z:
        meas = z.declare_publisher("vent/valve/insp/meas/flow", encoding=zenoh.Encoding.APPLICATION_JSON,
                                   priority=zenoh.Priority.REAL_TIME, express=True)
        cmd = z.declare_subscriber("vent/valve/insp/cmd/duty", zenoh.handlers.RingChannel(1024))
        pc = time.perf_counter
        seq, nxt, t_first = 0, pc(), None
        while True:
            now = pc()
            if now >= nxt:
                sent[seq] = pc()
                meas.put(json.dumps({"t": now, "seq": seq, "value": 30.0}).encode())
                seq += 1
                nxt += 1e-3
            while (x := cmd.try_recv()) is not None:
                k = json.loads(x.payload.to_bytes()).get("meas_seq")
                if k in sent:
                    rtt.append(pc() - sent.pop(k))
                    t_first = t_first or pc()
            if t_first is not None and pc() - t_first > SECONDS:
                break
            if t_first is None and now - sent.get(0, now) > 120:
                raise SystemExit("the controller never answered")
    ctrl.terminate()
    ctrl.wait(60)
    if echo:
        return None, np.array(rtt)
    with open(out) as fh:
        return json.load(fh), np.array(rtt)


#: The Zenoh part's fixed-rate baseline (``--baseline``): the controller of this commit, run from its own checkout,
#: interleaved with this tree's (Done-when: "the fixed-rate mode's figures do not get worse").
BASELINE_COMMIT = "725a272"


def in_process_schedulers(cfg, model) -> None:
    spin, rt = cfg.loop.spin_s, cfg.loop.rt_priority
    print("in-process simulated valve               lateness us                          compute us")
    base = None
    for name, s_, r_ in (("sleep to deadline (baseline)", 0.0, 0), (f"hybrid, spin {spin*1e6:.0f} us", spin, 0),
                         (f"hybrid + SCHED_FIFO {rt}", spin, rt)):
        s, cond = conditions(lambda: in_process(cfg, model, s_, r_))
        base = base or s["lateness_us"]["p99"]
        print(f"  {name:34s} {pct(s['lateness_us'])}   {pct(s['compute_us'])}   overruns {s['overruns']}, "
              f"p99 lateness {s['lateness_us']['p99'] / base:.3g}x baseline   ({cond})")


def in_process_compute(cfg, model, rounds: int) -> None:
    spin, rt = cfg.loop.spin_s, cfg.loop.rt_priority
    print("\nthe step's own work (compute us), make run's scheduling, rounds interleaved; baseline: the previous step")
    runs = {"previous: pure step, fresh arrays": {"previous": True},
            "now, no rehearsal": {"rehearse": False},
            "now, rehearsed (make run)": {}}
    got = {name: [] for name in runs}
    for k in range(rounds):
        for name, kw in runs.items():
            s, cond = conditions(lambda: in_process(cfg, model, spin, rt, **kw))
            got[name].append(s)
            print(f"    round {k + 1} {name:34s} compute p50 {s['compute_us']['p50']:6.1f} p99 "
                  f"{s['compute_us']['p99']:6.1f}   lateness p99 {s['lateness_us']['p99']:6.1f}   ({cond})")
    base = {q: np.median([s["compute_us"][q] for s in got["previous: pure step, fresh arrays"]]) for q in ("p50", "p99")}
    for name, ss in got.items():
        q = {k: np.median([s["compute_us"][k] for s in ss]) for k in ("p50", "p99")}
        b = {k: min(s["compute_us"][k] for s in ss) for k in ("p50", "p99")}
        tr = ss[0]["tracking"]
        iae, mae = (("-" if tr[k] is None else f"{tr[k]:.4f}") for k in ("iae", "steady_mae_lpm"))
        faults = ", ".join(f"{f['kind']} x{f['count']}" for f in ss[0]["faults"]) or "none"
        print(f"  {name:34s} compute median (best) of {rounds}: p50 {q['p50']:6.1f} ({b['p50']:5.1f}, "
              f"{q['p50'] / base['p50']:.2f}x)  p99 {q['p99']:6.1f} ({b['p99']:5.1f}, {q['p99'] / base['p99']:.2f}x)   "
              f"IAE {iae} L, steady MAE {mae} L/min, faults {faults}")
    now = got["now, rehearsed (make run)"]
    p50, p99 = (np.median([s["compute_us"][k] for s in now]) for k in ("p50", "p99"))
    print(f"  Done when (ff+kf, simulated valve): compute p50 <= 30 us: {p50:.1f} ({'met' if p50 <= 30 else 'NOT met'}), "
          f"p99 <= 60 us: {p99:.1f} ({'met' if p99 <= 60 else 'NOT met'})")


def over_zenoh(cfg, rounds: int, baseline: str | None) -> None:
    print("\nover Zenoh (controller process, this process as the valve), rounds interleaved")
    old = f"{baseline}, trigger period" if baseline else None
    tree = baseline_tree(baseline) if baseline else None
    names = ["bare Zenoh echo (baseline)", "loop, trigger period", *([old] if old else []), "loop, trigger measurement"]
    rtt = {name: [] for name in names}
    ctrl = {name: [] for name in names[1:]}
    for k in range(rounds):
        for name in rtt:
            if name.startswith("bare"):
                (s, x), cond = conditions(lambda: zenoh_round_trip(cfg, echo=True))
            else:
                trigger = name.rsplit(" ", 1)[1]
                (s, x), cond = conditions(lambda: zenoh_round_trip(cfg, trigger=trigger,
                                                                   tree=tree if name == old else None))
                ctrl[name].append(s)
                print(f"  {name:28s} controller lateness us {pct(s['lateness_us'])}   compute us "
                      f"{pct(s['compute_us'])}   overruns {s['overruns']} of {s['steps'] + s['overruns']}")
            rtt[name].append(np.percentile(x, [50, 99]) * 1e6)
            print(f"    round {k + 1} {name:28s} round trip p50 {rtt[name][-1][0]:6.0f} us   ({cond})")
    e50 = np.median([r[0] for r in rtt["bare Zenoh echo (baseline)"]])
    ratio = {}
    for name, r in rtt.items():
        p50, p99 = np.median([x[0] for x in r]), np.median([x[1] for x in r])
        ratio[name] = p50 / e50
        print(f"  round trip meas/flow -> cmd/duty, {name:28s} us: median over {rounds} rounds of p50 {p50:6.0f} "
              f"(best {min(x[0] for x in r):6.0f}), of p99 {p99:6.0f}  (p50 {p50 / e50:.2f}x baseline)")
    m = ratio["loop, trigger measurement"]
    print(f"  Done when: trigger measurement round trip p50 <= 1.5x the bare echo's: {m:.2f}x "
          f"({'met' if m <= 1.5 else 'NOT met'}); trigger period {ratio['loop, trigger period']:.2f}x")
    if old:
        med = {name: {f"{k} {q}": np.median([s[f"{k}_us"][q] for s in ss]) for k in ("compute", "lateness")
                      for q in ("p50", "p99")} | {"overruns": np.median([s["overruns"] for s in ss])}
               for name, ss in ctrl.items()}
        new_, old_ = med["loop, trigger period"], med[old]
        print(f"  Done when: the fixed-rate mode's figures do not get worse, this tree / {baseline} (medians over "
              f"{rounds} rounds): " + ", ".join(f"{k} {new_[k]:.1f} / {old_[k]:.1f} us ({new_[k] / old_[k]:.2f}x)"
                                               for k in new_ if k != "overruns")
              + f", overruns {new_['overruns']:g} / {old_['overruns']:g}, round trip p50 "
              f"{ratio['loop, trigger period'] / ratio[old]:.2f}x")
    print("  (trigger period reads its inputs once per period: the echo's round trip plus up to one period plus "
          "the step's compute; trigger measurement steps in the measurement's own Zenoh callback)")
    print("  (trigger period's round trip depends on the phase between this valve's clock and the loop's, set by "
          "when each process started: it ranges over a period from run to run; compare the controller's compute "
          "and lateness between runs, not that round trip)")


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--parts", default="schedulers,compute,zenoh",
                    help="comma-separated: schedulers (1a-c), compute (the step's own work), zenoh (2.)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the compute and Zenoh parts")
    ap.add_argument("--baseline", default=BASELINE_COMMIT,
                    help="commit whose fixed-rate controller runs beside this tree's over Zenoh ('' for none)")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    os.chdir(ROOT)
    cfg = load_run_config("config/run.toml")
    model = load_model(cfg.resolve(cfg[""]["model"]))
    print(f"loop at {cfg.loop.rate_hz:g} Hz, ff+kf, {SECONDS:g} s per case; shared 2-core machine, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    if "schedulers" in parts:
        in_process_schedulers(cfg, model)
    if "compute" in parts:
        in_process_compute(cfg, model, args.rounds)
    if "zenoh" in parts:
        over_zenoh(cfg, args.rounds, args.baseline or None)


if __name__ == "__main__":
    main()
