"""A closed-loop run: a controller drives the simulated valve in-process or a valve over Zenoh."""
from __future__ import annotations

import sys


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/run.toml", metavar="RUN.toml", help="run configuration (default %(default)s)")
    p.add_argument("--plant", choices=("sim", "zenoh"), default=None,
                   help="sim: the embedded simulated valve; zenoh: a valve (or valve-node) over Zenoh")
    p.add_argument("--controller", choices=("ff", "pid", "ff+pid", "ff+kf"), default=None)
    p.add_argument("--reference", choices=("profile", "zenoh"), default=None,
                   help="profile: the configured breath profile; zenoh: follow .../ref/flow")
    p.add_argument("--listen", action="append", default=None, metavar="EP", help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--connect", action="append", default=None, metavar="EP", help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="run length, s (0: until interrupted)")
    p.add_argument("--record", default=None, metavar="RUN.csv", help="one row per step, flushed as written")
    p.add_argument("--json", default=None, metavar="S.json", help="run summary (DESIGN.md)")
    p.add_argument("--plot", default=None, metavar="RUN.png", help="reference, flow, duty and error against time")


def run(args) -> int:
    import signal

    from models.model import load_model, write_json_atomic
    from models.recording import InputError, RecordingWriter

    from controller.config import controller_params, load_run_config, preview_s
    from controller.loop import RECORD_COLUMNS, Loop, ProfileReference
    from controller.run_summary import run_plot, summary, summary_text

    cfg = load_run_config(args.config)
    top = cfg[""]
    word = args.controller or top["controller"]
    plant_kind = args.plant or top["plant"]
    ref_kind = args.reference or top["reference"]
    duration = top["duration_s"] if args.duration is None else args.duration
    if duration < 0:
        raise InputError(f"--duration: must be >= 0, got {duration}")
    settings = cfg.loop
    model = load_model(cfg.resolve(top["model"]))
    preview = preview_s(cfg, ref_kind)
    params = controller_params(cfg, word, model)

    session = None
    if plant_kind == "zenoh" or ref_kind == "zenoh":
        from controller.transport.zenoh import EmbeddedValve, ZenohTransport, open_session

        session = open_session(cfg, args.listen, args.connect, role="controller")
        zt = ZenohTransport(session, cfg["zenoh"]["id"], settings.stale_ms * 1e-3)
    if plant_kind == "sim":
        from controller.transport.sim import SimTransport
        from plant_sim.plant import Plant, load_plant

        plant_params = load_plant(cfg.resolve(top["plant_config"]), effects=cfg["effects"])
        transport = SimTransport(Plant(plant_params, settings.rate_hz, seed=top["seed"]), settings.safe_duty_pct)
        if session is not None:
            transport = EmbeddedValve(transport, zt)
        plant_label = "sim " + ",".join(f"{k}={v:g}" for k, v in plant_params.effects.items())
    else:
        transport = zt
        plant_label = f"zenoh vent/valve/{cfg['zenoh']['id']}"
    if ref_kind == "profile":
        from plant_sim.protocols import BreathProfile

        try:
            profile = BreathProfile(**cfg["profile"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"{cfg.path}: section 'profile': {exc}") from None
        reference = ProfileReference(profile.value, preview)
    else:
        reference = zt.reference()

    writer = RecordingWriter(args.record, RECORD_COLUMNS) if args.record else None
    loop = Loop(params, transport, reference, settings, writer=writer)
    if sys.stderr.isatty():
        sys.stderr.write(f"running {word} on {plant_label} for {duration:g} s...\n")
    # SIGTERM or Ctrl-C end the run at the next step, with its summary.
    stopping: list[bool] = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True)) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        result = loop.run(duration if duration > 0 else None, stop=lambda: bool(stopping))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if writer is not None:
            writer.close()
        if session is not None:
            zt.close()
            session.close()
    s = summary(result, word, plant_label)
    print(summary_text(s))
    if args.json:
        write_json_atomic(args.json, s)
    if args.plot:
        run_plot(result.columns, args.plot, title=f"{word} on {plant_label}")
        print(f"plot -> {args.plot}")
    return 0
