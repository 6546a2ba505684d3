"""valvectl identify against valve-node twins: model, lag and delay, and the run configuration it writes.

For each twin (``config/valves/NAME``, here with a 15 ms lag, a 10 ms delay
and its 0.5 L/min sensor noise) and each protocol duration:

1. ``valvectl valve-node`` serves the twin; ``valvectl identify --duration S``
   characterizes it over Zenoh (loopback, free ports);
2. the identified model, behind its lag and delay, predicts the twin's
   noise-free flow on a held-out protocol (random holds and sines over the
   working range, never seen by the identification): RMSE;
3. the lag and delay against the twin's;
4. the run configuration it wrote, against the twin simulated in-process at
   exactly its rate (``sim``): IAE of each controller word with its gains
   against the sweep-tuned ``pid``, what the identification is worth without
   the missed periods of a loaded machine; and ``true``: ``ff+kf`` with the
   same gains but the twin's own model, lag and delay as its feedforward
   (the gap from ``ff+kf`` to ``true`` is the identification's, the rest the
   controller's and the noise's);
5. ``valvectl run --plant zenoh --config DIR/run.toml`` against a fresh node:
   steady MAE and IAE of the run's controller and of ``ff+kf``, and of ``pid``
   as the baseline measured in the same run: the PID the same sweep tuned
   (``IAE/pid``, same run configuration, same variants) and, with
   ``--shipped``, the twin's own ``run.toml`` PID gains (untuned for it,
   ``/shipped``); :data:`ROUNDS` interleaved runs each, IAE averaged.

Prints one table. Run it at idle priority: the valve-node, identify's session
and the runs (the real-time processes) get normal priority back, identify
drops to idle again once its session has ended (fits and sweep), and the
held-out and simulated figures are computed at idle priority. Each row
records the 1-minute load average at the start of identify and of the runs.
A duration given twice runs twice (``--duration 120 120``). Usage::

    chrt -i 0 nice -n 19 python bench/bench_identify.py [--twin pvp bench] [--duration 600 300 120] [--out DIR]
                                   [--tau-ms 15] [--delay-ms 10] [--noise L/min] [--effect WORD=VALUE ...]
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from controller.config import load_run_config  # noqa: E402
from controller.identify.estimate import predict_flow  # noqa: E402
from controller.sweep.spec import write_run_config  # noqa: E402
from models.model import load_model  # noqa: E402
from plant_sim import protocols  # noqa: E402
from plant_sim.plant import Plant, load_plant  # noqa: E402
from tests.zenoh_helpers import free_port  # noqa: E402

TAU_S, DELAY_S = 0.015, 0.010
NOISE_LPM = None  # the twin's own sensor noise (--noise changes it)
EFFECTS: dict = {}  # further effect words of the twin (--effect)
RT = True  # the twin's own loop.rt_priority (--no-rt: the normal scheduler)
SHIPPED = False  # also the twin's own run.toml PID gains as a baseline (--shipped)
RUN_S = 20.0
#: Closed-loop runs over Zenoh per controller, interleaved (IAE averaged).
ROUNDS = 2
#: Identifications run again after a safe stop (a stall of the shared machine longer than stale_ms).
RETRIES = 2


def twin_model(plant_toml: str) -> str:
    """The absolute path of the model file a plant.toml runs."""
    from models.tomlfile import read_toml

    return os.path.join(os.path.dirname(os.path.abspath(plant_toml)), read_toml(plant_toml)["model"])


def twin_config(name: str, folder: str) -> str:
    """The twin's run.toml with the lag and delay of the check, in ``folder``.

    The loop keeps the shipped real-time priority, as a user runs it: on this kernel a process at the
    normal policy wakes up to a scheduler slice late (p99 3.7 ms measured) even when every other process
    runs at SCHED_IDLE. ``--no-rt`` runs the normal policy instead (a shared machine's fallback)."""
    base = load_run_config(os.path.join(ROOT, "config", "valves", name, "run.toml"))
    s = copy.deepcopy(base.sections)
    s["effects"] = {"valve_dynamics": TAU_S, "transport_delay": DELAY_S, **EFFECTS}
    if NOISE_LPM is not None:  # the twin's plant.toml with another sensor noise
        plant = os.path.join(folder, "plant.toml")
        src = base.resolve(base[""]["plant_config"])
        with open(src) as fh:
            text = fh.read()
        text = "\n".join(f"model = {json.dumps(twin_model(src))}" if ln.startswith("model") else
                         (f"noise_lpm = {NOISE_LPM!r}" if ln.startswith("noise_lpm") else ln) for ln in text.splitlines())
        with open(plant, "w") as fh:
            fh.write(text + "\n")
        s[""]["plant_config"] = plant
    if not RT:
        s["loop"]["rt_priority"] = 0
    # A shared 2-core machine (load 15-25 while this ran) stalls processes for hundreds of ms and a node may
    # take long to start; each stall past the node's command timeout closes the valve and wipes its memory.
    s["identify"].update(stale_ms=5000.0, wait_s=120.0)
    s["valve_node"]["command_timeout_ms"] = 1000.0
    path = os.path.join(folder, f"twin_{name}.toml")
    write_run_config(dataclasses.replace(base, sections=s), path)
    return path


def _normal_priority() -> None:
    """In the child: the default policy at nice 0 (the bench itself may run at idle priority)."""
    os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    os.setpriority(os.PRIO_PROCESS, 0, 0)


def idle_priority(pid: int) -> None:
    """Every thread of ``pid`` to SCHED_IDLE (children it starts later inherit it)."""
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            os.sched_setscheduler(int(tid), os.SCHED_IDLE, os.sched_param(0))
        except (ProcessLookupError, PermissionError):
            pass


def valvectl(*args) -> subprocess.Popen:
    """``valvectl ARGS`` at normal priority: the real-time processes of the check."""
    return subprocess.Popen([sys.executable, "-m", "controller.cli", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_normal_priority)


def communicate_demoting(p: subprocess.Popen, csv_path: str, timeout_s: float):
    """``p.communicate()``, dropping ``p`` to idle priority once its recording ends with the safe row
    (the session is over; what follows is fits and the gain sweep, not real time)."""
    import threading

    done = threading.Event()

    def watch():
        while not done.wait(0.5):
            try:
                with open(csv_path, "rb") as fh:
                    fh.seek(max(0, os.path.getsize(csv_path) - 200))
                    tail = fh.read().decode(errors="replace").strip().splitlines()
            except OSError:
                continue
            if tail and ",safe," in tail[-1]:
                idle_priority(p.pid)
                return

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    try:
        return p.communicate(timeout=timeout_s)
    finally:
        done.set()


def node(cfg: str, ep: str, json_path: str, listen: bool = True) -> subprocess.Popen:
    """A valve-node on ``ep``: listening there (identify connects) or connecting to it (run listens)."""
    where = ["--listen", ep, "--connect", "tcp/127.0.0.1:1"] if listen else ["--connect", ep]
    return valvectl("valve-node", "--config", cfg, *where, "--json", json_path)


def stop(p: subprocess.Popen):
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
    return p.communicate(timeout=120)


#: The held-out protocol opens the valve from closed over this long, s (not scored).
OPENING_S = 2.0


def held_out_duty(lo_pct: float, hi_pct: float, rate_hz: float) -> tuple[np.ndarray, int]:
    """The held-out protocol over the working range and the row its scoring starts at.

    The valve starts closed (at rest at 0 % duty, as it is at power-up, when the
    identification starts and when the loop's feedforward starts from the safe duty) and
    opens to ``lo_pct``; then random holds (minor loops at random places) and sines of
    20, 5 and 1 s period over the whole range. Starting it at rest mid-range instead
    would score a memory state no valve is in: a model's operators relaxed at a level
    the valve was never held at.
    """
    n0 = int(round(OPENING_S * rate_hz))
    duty = np.concatenate([np.zeros(n0 // 2), np.linspace(0.0, lo_pct, n0 - n0 // 2),
                           protocols.random_holds(rate_hz, 60.0, seed=7, lo_pct=lo_pct, hi_pct=hi_pct,
                                                  hold_s=(0.3, 3.0)),
                           protocols.sines(rate_hz, 60.0, center_pct=(lo_pct + hi_pct) / 2,
                                           amplitude_pct=(hi_pct - lo_pct) / 2, periods_s=(20.0, 5.0, 1.0))])
    return duty, n0


def held_out_rmse(plant_params, model, tau_s: float, delay_s: float, lo_pct: float, hi_pct: float) -> float:
    """RMSE (L/min) of ``model`` behind its lag and delay against the twin's noise-free flow, held-out protocol."""
    rate = 1000.0
    duty, n0 = held_out_duty(lo_pct, hi_pct, rate)
    true = Plant(plant_params, rate, seed=0).simulate(duty)["true_flow_lpm"]
    # the plant's row k is its answer to the duty of row k, read one period later by a loop
    pred = predict_flow(model, duty, rate, tau_s, delay_s + 1.0 / rate)
    e = (pred[1:] - true[:-1])[n0:]
    return float(np.sqrt(np.mean(e * e)))


def identified_held_out_rmse(cfg_path: str, out: str) -> float:
    """:func:`held_out_rmse` of the identification in ``out`` against the twin of ``cfg_path``."""
    cfg = load_run_config(cfg_path)
    plant_params = load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"])
    summ = json.load(open(os.path.join(out, "identify.json")))
    return held_out_rmse(plant_params, load_model(os.path.join(out, "model.json")), summ["tau_s"], summ["delay_s"],
                         summ["working_range"]["lo_pct"], summ["working_range"]["hi_pct"])


def simulated_closed_loop(cfg_path: str, out: str) -> dict:
    """IAE and steady MAE per controller word of the identified run against the twin simulated in-process.

    The run configuration ``identify`` wrote, with its gains, drives the twin at exactly its
    rate (the sweep's simulator, which is the live loop step for step): what the
    identification is worth without the loaded machine's missed periods.
    """
    from controller.sweep import runner
    from controller.sweep.spec import load_sweep

    twin = load_run_config(cfg_path)
    run = load_run_config(os.path.join(out, "run.toml"))
    s = copy.deepcopy(run.sections)
    s[""].update(plant="sim", plant_config=twin.resolve(twin[""]["plant_config"]))
    s["effects"] = dict(twin["effects"])
    folder = os.path.join(out, "twin_sim")
    os.makedirs(folder, exist_ok=True)
    write_run_config(dataclasses.replace(run, sections=s), os.path.join(folder, "run.toml"))
    gains = json.load(open(os.path.join(out, "identify.json")))["gains"]
    lines = ['run = "run.toml"', f"duration_s = {RUN_S!r}", 'objective = "iae"', "margins_top = 0", "", "[[variants]]"]
    # the twin's own model, lag and delay as ff+kf's feedforward, with the identified gains: what is left
    # between this and the identified ff+kf is the identification's; between this and the floor, the controller's
    true = {"model": twin_model(twin.resolve(twin[""]["plant_config"])),
            "valve.tau_s": twin["effects"]["valve_dynamics"], "valve.delay_s": twin["effects"]["transport_delay"]}
    for word, params in [*gains.items(), ("ff+kf", {**gains["ff+kf"], **true})]:
        lines += ["", "[[candidates]]", f'controller = "{word}"', 'sample = "grid"']
        lines += [f"{k} = [{json.dumps(v)}]" for k, v in params.items() if k != "controller"]
    with open(os.path.join(folder, "sweep.toml"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    res = runner.run_sweep(load_sweep(os.path.join(folder, "sweep.toml")), None, 1)
    t = res.table
    words = [*gains, "ff+kf true model"]
    return {w: {"iae": float(t["iae"][i]), "steady_mae_lpm": float(t["steady_mae_lpm"][i])}
            for w, i in zip(words, range(1, len(t["controller"])))}


def closed_loop(cfg: str, run_toml: str, out: str, word: str | None) -> dict:
    ep = f"tcp/127.0.0.1:{free_port()}"
    tag = f"{word or 'default'}{'_shipped' if run_toml == cfg else ''}"
    load1 = os.getloadavg()[0]
    n = node(cfg, ep, os.path.join(out, f"n_run_{tag}.json"), listen=False)
    s_json = os.path.join(out, f"run_{tag}.json")
    args = ["run", "--plant", "zenoh", "--config", run_toml, "--listen", ep, "--duration", str(RUN_S), "--json", s_json]
    if word:
        args += ["--controller", word]
    try:
        r = valvectl(*args)
        so, se = r.communicate(timeout=600)
    finally:
        stop(n)
    if r.returncode != 0:
        raise RuntimeError(f"run {word}: {se.strip()[-400:]}")
    return {**json.load(open(s_json)), "load1": load1}


def one(name: str, duration: float, root: str, repeat: int = 0) -> dict:
    folder = os.path.join(root, name, f"{int(duration)}s" + (f"_{repeat}" if repeat else ""))
    os.makedirs(folder, exist_ok=True)
    cfg = twin_config(name, folder)
    out = os.path.join(folder, "id")
    aborts = []
    for _ in range(1 + RETRIES):
        ep = f"tcp/127.0.0.1:{free_port()}"
        n = node(cfg, ep, os.path.join(folder, "n_identify.json"))
        t0 = time.perf_counter()
        id_load1 = os.getloadavg()[0]
        try:
            p = valvectl("identify", "--config", cfg, "--connect", ep, "--listen", f"tcp/127.0.0.1:{free_port()}",
                         "--duration", str(duration), "-o", out)
            so, se = communicate_demoting(p, os.path.join(out, "identification.csv"), duration + 1800)
        finally:
            stop(n)
        wall = time.perf_counter() - t0
        if p.returncode != 1 or "aborted" not in se:
            break
        aborts.append(se.strip()[-300:])  # a stall of the loaded machine longer than stale_ms: the session stopped safely
    if p.returncode != 0:
        raise RuntimeError(f"identify {name} {duration}: {se.strip()[-400:]}")
    summ = json.load(open(os.path.join(out, "identify.json")))
    nj = json.load(open(os.path.join(folder, "n_identify.json")))
    row = {"twin": name, "duration_s": summ["duration_s"], "wall_s": wall, "model": summ["model"],
           "tau_ms": summ["tau_s"] * 1e3, "delay_ms": summ["delay_s"] * 1e3,
           "tau_err": summ["tau_s"] / TAU_S - 1, "delay_err": summ["delay_s"] / DELAY_S - 1,
           "val_rmse": summ["validation"]["rmse"],
           "round_trip_p50_us": nj["round_trip_us"]["p50"], "controller": summ["controller"], "aborts": aborts,
           "id_load1": id_load1, "id_periods": summ.get("steps"),
           "id_overruns": summ["overruns"], "id_timeline": summ.get("timeline"), "steps_read": summ["dynamics"]["steps"],
           "steps_disturbed": summ["dynamics"]["steps_disturbed"]}
    run_toml = os.path.join(out, "run.toml")
    runs: dict = {}
    for _ in range(ROUNDS):  # interleaved, so the words and the baseline share the machine's load
        for tag, word, toml in (("best", None, run_toml), ("pid", "pid", run_toml), ("ff+kf", "ff+kf", run_toml),
                                ("shipped", "pid", cfg)):  # shipped: the twin's own run.toml gains, untuned for it
            if (tag == "ff+kf" and summ["controller"] == "ff+kf") or (tag == "shipped" and not SHIPPED):
                continue
            runs.setdefault(tag, []).append(closed_loop(cfg, toml, folder, word))
    runs.setdefault("ff+kf", runs["best"])

    def mean(tag, key):
        return float(np.mean([r["tracking"][key] for r in runs[tag]]))

    row.update(steady_mae=mean("best", "steady_mae_lpm"), iae=mean("best", "iae"), iae_pid=mean("pid", "iae"),
               steady_mae_pid=mean("pid", "steady_mae_lpm"), iae_ffkf=mean("ff+kf", "iae"),
               steady_mae_ffkf=mean("ff+kf", "steady_mae_lpm"),
               iae_pid_shipped=mean("shipped", "iae") if SHIPPED else float("nan"),
               faults=sorted({f["kind"] for r in runs["best"] for f in r["faults"]}),
               overruns=sum(r["overruns"] for r in runs["best"]), overruns_pid=sum(r["overruns"] for r in runs["pid"]),
               faults_pid=sorted({f["kind"] for r in runs["pid"] for f in r["faults"]}),
               run_load1=[r["load1"] for tag in runs for r in runs[tag]], load1=os.getloadavg()[0])
    row["iae_ratio"] = row["iae"] / row["iae_pid"]
    row["iae_ratio_ffkf"] = row["iae_ffkf"] / row["iae_pid"]
    row["iae_ratio_shipped"] = row["iae"] / row["iae_pid_shipped"]
    return row, cfg, out


def offline(row: dict, cfg: str, out: str) -> dict:
    """``row`` with the figures computed in-process (held-out RMSE, the simulated closed loop), written to
    ``bench.json`` beside the identification."""
    row = dict(row, held_out_rmse=identified_held_out_rmse(cfg, out))
    sim = simulated_closed_loop(cfg, out)
    row.update(sim_iae={w: v["iae"] for w, v in sim.items()}, sim_steady_mae={w: v["steady_mae_lpm"] for w, v in sim.items()})
    row["sim_iae_ratio"] = sim[row["controller"]]["iae"] / sim["pid"]["iae"]
    row["sim_iae_ratio_ffkf"] = sim["ff+kf"]["iae"] / sim["pid"]["iae"]
    row["sim_iae_ratio_true"] = sim["ff+kf true model"]["iae"] / sim["pid"]["iae"]
    with open(os.path.join(os.path.dirname(out), "bench.json"), "w") as fh:
        json.dump(row, fh, indent=1)
    return row


def main() -> None:
    global TAU_S, DELAY_S, NOISE_LPM, EFFECTS, SHIPPED, RT
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--twin", nargs="+", default=["pvp", "bench"])
    ap.add_argument("--duration", nargs="+", type=float, default=[600.0])
    ap.add_argument("--out", default="/tmp/bench_identify")
    ap.add_argument("--tau-ms", type=float, default=TAU_S * 1e3, help="the twin's lag")
    ap.add_argument("--delay-ms", type=float, default=DELAY_S * 1e3, help="the twin's delay")
    ap.add_argument("--noise", type=float, default=None, help="the twin's sensor noise, L/min (default: its own)")
    ap.add_argument("--shipped", action="store_true",
                    help="also run pid with the twin's own run.toml gains (untuned for this lag and delay)")
    ap.add_argument("--effect", nargs="*", default=[], metavar="WORD=VALUE",
                    help="further effect words of the twin (a valve the identified kinds do not describe)")
    ap.add_argument("--no-rt", action="store_true",
                    help="run the loops at the normal scheduler, not the twin's SCHED_FIFO rt_priority")
    a = ap.parse_args()
    RT = not a.no_rt
    TAU_S, DELAY_S, NOISE_LPM = a.tau_ms * 1e-3, a.delay_ms * 1e-3, a.noise
    EFFECTS = {k: float(v) for k, v in (e.split("=", 1) for e in a.effect)}
    SHIPPED = a.shipped
    # the in-process figures of one identification are computed while the next one runs over Zenoh
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(1) as pool:
        pending = []
        for i, d in enumerate(a.duration):  # durations outer: a long list gives every twin each duration early
            for name in a.twin:
                pending.append(pool.submit(offline, *one(name, d, a.out, a.duration[:i].count(d))))
        rows = []
        for f in pending:
            rows.append(f.result())
            print(json.dumps(rows[-1]), flush=True)
    print(f"\n{'twin':<6}{'dur s':>7}{'model':>9}{'tau ms':>8}{'err':>7}{'delay ms':>9}{'err':>7}{'held-out':>9}"
          f"{'ctrl':>8}{'st.MAE':>8}{'IAE/pid':>8}{'ff+kf':>7}{'st.MAE':>8}{'/shipped':>9}{'sim':>6}{'ff+kf':>7}"
          f"{'true':>6}{'id ovr':>8}{'run ovr':>8}{'faults':>14}{'load id/run':>13}")
    for r in rows:
        print(f"{r['twin']:<6}{r['duration_s']:7.0f}{r['model']:>9}{r['tau_ms']:8.2f}{r['tau_err']:7.1%}"
              f"{r['delay_ms']:9.2f}{r['delay_err']:7.1%}{r['held_out_rmse']:9.2f}{r['controller']:>8}"
              f"{r['steady_mae']:8.2f}{r['iae_ratio']:8.2f}{r['iae_ratio_ffkf']:7.2f}{r['steady_mae_ffkf']:8.2f}"
              f"{r['iae_ratio_shipped']:9.2f}{r['sim_iae_ratio']:6.2f}{r['sim_iae_ratio_ffkf']:7.2f}"
              f"{r['sim_iae_ratio_true']:6.2f}{r['id_overruns'] / max((r['id_periods'] or 0) + r['id_overruns'], 1):8.1%}"
              f"{r['overruns']:8d}{','.join(r['faults'] + r['faults_pid']) or '-':>14}"
              f"{r['id_load1']:7.1f}/{max(r['run_load1']):.1f}")


if __name__ == "__main__":
    main()
