"""A closed-loop run: a controller drives the simulated valve in-process or a valve over Zenoh."""
from __future__ import annotations

import sys


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/run.toml", metavar="RUN.toml", help="run configuration (default %(default)s)")
    p.add_argument("--plant", choices=("sim", "zenoh"), default=None,
                   help="sim: the embedded simulated valve; zenoh: a valve (or valve-node) over Zenoh")
    p.add_argument("--controller", choices=("ff", "pid", "ff+pid", "ff+kf"), default=None,
                   help="the controller at the start (.../ctrl/mode switches it while running)")
    p.add_argument("--reference", default=None, metavar="profile|zenoh|FILE.csv",
                   help="profile: the configured breath profile; zenoh: follow .../ref/flow; "
                        "FILE.csv: replay a recorded reference (t_s, ref_lpm)")
    p.add_argument("--listen", action="append", default=None, metavar="EP", help="Zenoh endpoint to listen on (repeatable; with --plant sim: publish ctrl/status and ctrl/error there)")
    p.add_argument("--connect", action="append", default=None, metavar="EP", help="Zenoh endpoint to connect to (repeatable)")
    p.add_argument("--certs", default=None, metavar="DIR",
                   help="TLS with mutual authentication and access control, as role controller "
                        "(files of `valvectl certs DIR`)")
    p.add_argument("--trigger", choices=("period", "measurement"), default=None,
                   help="a step every period, or as each measurement arrives (--plant zenoh); default: [loop] trigger")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="run length, s (0: until interrupted; default: the configuration's, or a FILE reference's span)")
    p.add_argument("--record", default=None, metavar="RUN.csv", help="one row per step, flushed as written")
    p.add_argument("--json", default=None, metavar="S.json", help="run summary (DESIGN.md)")
    p.add_argument("--plot", default=None, metavar="RUN.png", help="reference, flow, duty split and error against time")
    p.add_argument("--report", default=None, metavar="DIR", help="Markdown report with the summary and the run plot")
    p.add_argument("--inject", action="append", default=[], metavar="NAME=VALUE@T",
                   help="simulated valve only: set a plant setting or effect word to VALUE at T s, e.g. "
                        "supply_bar=0.3@9.2 (repeatable)")


def parse_inject(text: str) -> tuple[float, str, float]:
    """``NAME=VALUE@T`` -> ``(t_s, name, value)``; bad text is an InputError naming it."""
    from models.recording import InputError

    try:
        setting, at = text.rsplit("@", 1)
        name, value = setting.split("=", 1)
        t_s, v = float(at), float(value)
    except ValueError:
        raise InputError(f"--inject {text}: expected NAME=VALUE@T (e.g. supply_bar=0.3@9.2)") from None
    if not (0 <= t_s < float("inf")) or not abs(v) < float("inf"):
        raise InputError(f"--inject {text}: T must be a finite time >= 0 s and VALUE a finite number")
    return t_s, name.strip(), v


def _check_steps(duration_s: float, rate_hz: float, what: str) -> None:
    """A run's length in steps within what its record can hold (:data:`models.recording.MAX_SAMPLES`)."""
    from models.recording import MAX_SAMPLES, InputError

    if duration_s * rate_hz > MAX_SAMPLES:
        raise InputError(f"{what}: {duration_s:g} s at {rate_hz:g} Hz is {duration_s * rate_hz:.3g} steps, more than "
                         f"the {MAX_SAMPLES:.0e} a run records (0 runs until interrupted)")


def run(args) -> int:
    import dataclasses
    import signal

    from models.atomicfile import save_figure_atomic
    from models.model import load_model, write_json_atomic
    from models.recording import InputError, RecordingWriter

    from controller.config import load_run_config, preview_s, supervisor
    from controller.loop import RECORD_COLUMNS, Loop, ProfileReference
    from controller.run_summary import RunResult, summary_text

    from controller.commands.outputs import check_outputs

    check_outputs(args)
    cfg = load_run_config(args.config)
    top = cfg[""]
    word = args.controller or top["controller"]
    plant_kind = args.plant or top["plant"]
    ref_kind = args.reference or top["reference"]
    duration = top["duration_s"] if args.duration is None else args.duration
    if not (0 <= duration < float("inf")):
        raise InputError(f"--duration: must be a finite number of seconds >= 0 (0: until interrupted), got {duration}")
    _check_steps(duration, settings_rate := cfg["loop"]["rate_hz"],
                 "--duration" if args.duration is not None else f"{cfg.path}: duration_s")
    injections = [parse_inject(x) for x in args.inject]
    settings = cfg.loop if args.trigger is None else dataclasses.replace(cfg.loop, trigger=args.trigger)
    if settings.trigger == "measurement" and plant_kind != "zenoh":
        raise InputError(f"{cfg.path}: loop.trigger = \"measurement\" needs a valve over Zenoh (--plant zenoh): "
                         "the embedded simulated valve has no clock of its own")
    if injections and plant_kind != "sim":
        raise InputError("--inject: only the simulated valve (--plant sim) can be changed mid-run")
    model = load_model(cfg.resolve(top["model"]))
    recorded = None
    if ref_kind not in ("profile", "zenoh"):
        from controller.reference import RecordedReference

        recorded = RecordedReference(ref_kind)
        if args.duration is None:
            if not recorded.span_s > 0:
                raise InputError(f"{ref_kind}: a reference of one instant (its span is 0 s) sets no run length; "
                                 "give --duration")
            duration = recorded.span_s
            _check_steps(duration, settings_rate, f"{ref_kind}: column 't_s' (its span)")
    preview = preview_s(cfg, "zenoh" if ref_kind == "zenoh" else "profile")
    sup = supervisor(cfg, word, model)

    session = None
    # A simulated valve publishes the controller's error and status too when endpoints are given
    # (`valvectl run --listen EP`: a monitor can watch an in-process run).
    if plant_kind == "zenoh" or ref_kind == "zenoh" or args.listen or args.connect:
        from controller.transport.zenoh import EmbeddedValve, ZenohTransport, open_session

        session = open_session(cfg, args.listen, args.connect, role="controller", certs=args.certs)
        zt = ZenohTransport(session, cfg["zenoh"]["id"], settings.stale_ms * 1e-3, settings.trigger)
    if plant_kind == "sim":
        from controller.transport.sim import SimTransport
        from plant_sim.plant import Plant, load_plant

        plant_params = load_plant(cfg.resolve(top["plant_config"]), effects=cfg["effects"])
        from plant_sim.plant import PlantSettings

        for _, name, value in injections:  # a bad name or value is bad input now, not mid-run
            if name not in PlantSettings.__struct_fields__:  # not the model, nor anything else of PlantParams
                raise InputError(f"--inject {name}: not a plant setting or effect word")
            try:
                plant_params.replace(**{name: value})
            except InputError as exc:  # the plant schema's own line: "plant: FIELD: problem (got VALUE)"
                raise InputError(f"--inject {name}={value:g}: {str(exc).removeprefix('plant: ')}") from None
        transport = SimTransport(Plant(plant_params, settings.rate_hz, seed=top["seed"]), settings.safe_duty_pct,
                                 injections)
        if session is not None:
            transport = EmbeddedValve(transport, zt)
        plant_label = "sim " + ",".join(f"{k}={v:g}" for k, v in plant_params.effects.items())
    else:
        transport = zt
        plant_label = f"zenoh vent/valve/{cfg['zenoh']['id']}"
    if ref_kind == "zenoh":
        reference = zt.reference()
    elif recorded is not None:
        reference = ProfileReference(recorded, preview)
    else:
        from plant_sim.protocols import BreathProfile

        try:
            profile = BreathProfile(**cfg["profile"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"{cfg.path}: section 'profile': {exc}") from None
        reference = ProfileReference(profile.value, preview)

    writer = RecordingWriter(args.record, RECORD_COLUMNS) if args.record else None
    observer = None
    if sys.stderr.isatty():
        sys.stderr.write(f"running {word} on {plant_label} for "
                         + (f"{duration:g} s" if duration > 0 else "until interrupted") + " (Ctrl-C ends it)\n")

        def observer(t_s: float, st: dict) -> None:
            alarms = ",".join(st["alarms"]) or "-"
            sys.stderr.write(f"\r{t_s:8.1f} s  {st['state']:<7} {st['controller']:<6}  IAE {st['iae']:.4f} L  "
                             f"overruns {st['overruns']}  alarms {alarms}   ")
            sys.stderr.flush()
    loop = Loop(sup, transport, reference, settings, writer=writer, observer=observer)
    # SIGTERM or Ctrl-C end the run at the next step, with its summary.
    stopping: list[bool] = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True)) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        result = loop.run(duration if duration > 0 else None, stop=lambda: bool(stopping))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if observer is not None:
            sys.stderr.write("\n")
        if writer is not None:
            writer.close()
        if session is not None:
            zt.close()
            session.close()
    res = RunResult(result, word, plant_label)
    s = res.summary()
    print(summary_text(s))
    if args.json:
        write_json_atomic(args.json, s)
    if args.plot:
        save_figure_atomic(res.plot(), args.plot, dpi=110)
        print(f"plot -> {args.plot}")
    if args.report:
        print(f"report -> {res.write_report(args.report)}")
    return 0
