"""Live view of a running controller over Zenoh: state, controller, signals with sparklines, timing, faults, alarms."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/run.toml", metavar="RUN.toml",
                   help="run configuration: [zenoh] id and endpoints (default %(default)s)")
    p.add_argument("--connect", action="append", default=None, metavar="EP",
                   help="Zenoh endpoint to connect to (repeatable; default: the controller's listen endpoints)")
    p.add_argument("--duration", type=float, default=0.0, metavar="S", help="stop after S seconds (0: until interrupted)")
    p.add_argument("--certs", default=None, metavar="DIR",
                   help="TLS with mutual authentication and access control, as role monitor "
                        "(read-only; files of `valvectl certs DIR`)")
    p.add_argument("--record", default=None, metavar="M.csv",
                   help="one row per ctrl/status received: t_s, state, controller, ref_lpm, flow_lpm, duty_pct, "
                        "error_lpm, alarms (flushed as written)")


def run(args) -> int:
    import signal
    import sys
    import time

    from rich.console import Console
    from rich.live import Live

    from models.recording import InputError, RecordingWriter

    from controller.config import load_run_config
    from controller.monitor import MONITOR_COLUMNS, MonitorState, parse_status, render
    from controller.transport.payload import PayloadError
    from controller.transport.zenoh import open_session, raw_payload, zenoh

    from controller.commands.outputs import check_outputs

    if not 0 <= args.duration < float("inf"):
        raise InputError(f"--duration: must be a finite number of seconds >= 0 (0: until interrupted), "
                         f"got {args.duration}")
    check_outputs(args, files=("record",), folders=())
    cfg = load_run_config(args.config)
    key = f"vent/valve/{cfg['zenoh']['id']}/ctrl/status"
    session = open_session(cfg, None, args.connect, role="monitor", certs=args.certs)
    sub = session.declare_subscriber(key, zenoh.handlers.RingChannel(64))
    writer = RecordingWriter(args.record, MONITOR_COLUMNS) if args.record else None
    m = MonitorState()
    source = " ".join(args.connect or cfg["zenoh"]["connect"] or cfg["zenoh"]["listen"])
    stopping: list[bool] = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True)) for sig in (signal.SIGTERM, signal.SIGINT)}
    console = Console()
    t0 = last = time.monotonic()
    try:
        with Live(render(m, source), console=console, refresh_per_second=10, transient=False) as live:
            while not stopping and not (args.duration > 0 and time.monotonic() - t0 >= args.duration):
                got = False
                while (sample := sub.try_recv()) is not None:  # every status since the last poll, in order
                    try:
                        msg = parse_status(raw_payload(sample))
                    except PayloadError:
                        m.bad += 1
                        continue
                    got = True
                    row = m.add(msg.t_s, msg.value)
                    if writer is not None:
                        writer.write(row)
                now = time.monotonic()
                if got:
                    last = now
                live.update(render(m, source, now - last, width=min(60, max(10, console.width - 60))))
                time.sleep(0.05)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if writer is not None:
            writer.close()
        sub.undeclare()
        session.close()
    sys.stderr.write(f"monitor: {m.received} statuses received, {m.bad} malformed\n")
    return 0
