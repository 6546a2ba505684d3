"""Characterize a valve over Zenoh (open loop, safe limits), fit it, and write a run configuration for it.

Writes to DIR: identification.csv (the recording, flushed as it is written),
model.json, plant.toml, run.toml, sweep.toml, sweep.csv, report.md with its
PNGs, and identify.json. Ctrl-C, SIGTERM, a stale measurement or a flow
above [identify] flow_limit_lpm command the safe duty at once; identify.json
then says "aborted": true (exit 130 for a signal, 1 otherwise).
"""
from __future__ import annotations

import os
import sys


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/run.toml", metavar="RUN.toml",
                   help="run configuration: [identify], [limits], [loop], [zenoh] (default %(default)s)")
    p.add_argument("--listen", action="append", default=None, metavar="EP", help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--connect", action="append", default=None, metavar="EP", help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="valve time of the protocol, s (default [identify] duration_s)")
    p.add_argument("--certs", default=None, metavar="DIR",
                   help="TLS with mutual authentication and access control, as role controller "
                        "(files of `valvectl certs DIR`)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")


def _bar(total: float, desc: str, unit: str):
    from tqdm import tqdm

    # shown only when stderr is a terminal (disable=None)
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=None, leave=False,
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} {unit} [{elapsed}<{remaining}]")


def run(args) -> int:
    import signal

    from models.model import write_json_atomic
    from models.recording import InputError, RecordingWriter

    from controller.config import load_run_config
    from controller.identify.link import Link
    from controller.identify.protocol import Program, ProtocolParams
    from controller.identify.report import summary_json
    from controller.identify.session import Safety, record_columns, run_session
    from controller.loop import RealClock, realtime
    from controller.transport.zenoh import open_session

    cfg = load_run_config(args.config)
    idc, lim, lp = cfg["identify"], cfg["limits"], cfg["loop"]
    duration = idc["duration_s"] if args.duration is None else args.duration
    rate = lp["rate_hz"]
    if not lim["duty_min_pct"] <= lp["safe_duty_pct"] <= lim["duty_max_pct"]:
        raise InputError(f"{cfg.path}: key 'loop.safe_duty_pct': {lp['safe_duty_pct']:g} outside the duty limits")
    params = ProtocolParams(duration, rate, lim["duty_min_pct"], lim["duty_max_pct"], 0.9 * idc["flow_limit_lpm"],
                            idc["seed"])
    safety = Safety(lim["duty_min_pct"], lim["duty_max_pct"], lp["safe_duty_pct"], idc["stale_ms"] * 1e-3,
                    idc["flow_limit_lpm"])
    out = args.output
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        raise InputError(f"-o {out}: cannot create the folder ({exc.strerror})") from None

    session = open_session(cfg, args.listen, args.connect, role="controller", certs=args.certs)
    link = Link(session, cfg["zenoh"]["id"], safety.stale_s)
    writer = None
    stopping: list[bool] = []
    previous = {}
    try:
        aux = link.wait_for_valve(idc["wait_s"])
        link.claim()
        previous = {sig: signal.signal(sig, lambda n, _f: stopping.append(n)) for sig in (signal.SIGTERM, signal.SIGINT)}
        writer = RecordingWriter(os.path.join(out, "identification.csv"), record_columns(aux))
        bar = _bar(round(duration), "identify", "s")

        def progress(fraction, phase):
            bar.n = fraction * duration
            bar.set_description(phase, refresh=False)
            bar.refresh()

        with realtime(lp["rt_priority"]):
            res = run_session(Program(params), link, safety, rate, RealClock(lp["spin_us"] * 1e-6), writer,
                              stop=lambda: bool(stopping), progress=progress, aux=aux,
                              catch_up=lp["catch_up"])
        bar.close()
    finally:
        if writer is not None:
            writer.close()
        link.close()
        session.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    from controller.identify.analysis import Damaged, damage_of, identify

    if res.aborted:
        write_json_atomic(os.path.join(out, "identify.json"), summary_json(res, damage=damage_of(res, rate)))
        sys.stderr.write(f"valvectl identify: aborted ({res.message or res.reason}) after {res.duration_s:.1f} s: valve at the "
                         f"safe duty {safety.safe_duty_pct:g} %; recording {writer.path} complete to that point\n")
        return 130 if res.reason == "interrupted" else 1

    from controller.identify.report import write_report
    from controller.identify.tune import tune_identified
    from models.fitting import KINDS

    bar = _bar(len(KINDS), "fit", "kinds")
    try:
        ident = identify(res, rate, progress=lambda k: (bar.set_description(f"fit {k}"), bar.update(1)))
    except Damaged as exc:
        write_json_atomic(os.path.join(out, "identify.json"), summary_json(res, damage=damage_of(res, rate)))
        sys.stderr.write(f"valvectl identify: refused: {exc}\n")
        return 1
    except ValueError as exc:
        sys.stderr.write(f"valvectl identify: {exc}\n")
        return 1
    finally:
        bar.close()
    dyn, est = ident.dynamics, ident.estimate
    if ident.warning:
        sys.stderr.write(f"valvectl identify: warning: {ident.warning}\n")
    if not dyn.clean:
        from controller.identify.report import NOT_CLEAN

        sys.stderr.write(f"valvectl identify: warning: {NOT_CLEAN}\n")
    try:
        tuning = tune_identified(cfg, out, est, dyn, idc["seed"], idc["tune_candidates"], res.working_range.span_pct)
    except ValueError as exc:
        sys.stderr.write(f"valvectl identify: {exc}\n")
        return 1
    report = write_report(out, res, ident, tuning)
    summ = summary_json(res, est, dyn, tuning, ident.damage, ident.coil_ref_c)
    write_json_atomic(os.path.join(out, "identify.json"), summ)
    v = summ["validation"]
    print(f"identified in {res.duration_s:.0f} s: range {res.working_range.lo_pct:.1f}..{res.working_range.hi_pct:.1f} %, "
          f"tau {dyn.tau_s * 1e3:.1f} ± {dyn.tau_se_s * 1e3:.1f} ms, delay {dyn.delay_s * 1e3:.1f} ± "
          f"{dyn.delay_se_s * 1e3:.1f} ms; model {est.chosen} (validation MAE {v['mae']:.2f}, RMSE {v['rmse']:.2f} "
          f"L/min); controller {tuning.controller} -> {tuning.run_path}, {report}")
    return 0
