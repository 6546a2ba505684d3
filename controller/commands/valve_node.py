"""The simulated valve as a Zenoh node (stand-in for the hardware bridge): cmd/duty in, meas/flow out."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/run.toml", metavar="RUN.toml",
                   help="run configuration: its plant_config is the valve served, with [effects], [valve_node], "
                        "[zenoh] (default %(default)s)")
    p.add_argument("--listen", action="append", default=None, metavar="EP", help="Zenoh endpoint to listen on (repeatable)")
    p.add_argument("--connect", action="append", default=None, metavar="EP",
                   help="Zenoh endpoint to connect to (repeatable; default: the controller's listen endpoints)")
    p.add_argument("--certs", default=None, metavar="DIR",
                   help="TLS with mutual authentication and access control, as role valve "
                        "(files of `valvectl certs DIR`)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default or 0: until interrupted)")
    p.add_argument("--json", default=None, metavar="N.json",
                   help='{"steps","overruns","commands","bad_commands","command_timeouts","round_trip_us":{"p50","p99"},'
                        '"compute_us":{"max"},"publish_gap_ms":{"max"}} (compute: the longest step, wake to end; '
                        'publish gap: the longest time between two published measurements)')


def run(args) -> int:
    import signal

    from models.recording import InputError

    from controller.config import load_run_config
    from controller.loop import RealClock, realtime
    from controller.transport.zenoh import ValveNodeTransport, open_session
    from controller.valve_node import ValveNode
    from models.model import write_json_atomic
    from plant_sim.plant import Plant, load_plant

    if args.duration is not None and not (0 <= args.duration < float("inf")):
        raise InputError(f"--duration: must be a finite number of seconds >= 0 (0: until interrupted), "
                         f"got {args.duration}")
    duration = args.duration or None  # 0: until interrupted
    from controller.commands.outputs import check_outputs

    check_outputs(args, files=("json",), folders=())  # before the run, not after it
    cfg = load_run_config(args.config)
    node_cfg = cfg["valve_node"]
    plant = Plant(load_plant(cfg.resolve(cfg[""]["plant_config"]), effects=cfg["effects"]), node_cfg["rate_hz"],
                  seed=cfg[""]["seed"])
    # SIGTERM or Ctrl-C end the node at its next step, with its summary.
    stopping: list[bool] = []
    previous = {sig: signal.signal(sig, lambda *_: stopping.append(True)) for sig in (signal.SIGTERM, signal.SIGINT)}
    session = open_session(cfg, args.listen, args.connect, role="valve", certs=args.certs)
    transport = ValveNodeTransport(session, cfg["zenoh"]["id"])
    node = ValveNode(plant, transport, node_cfg["rate_hz"], node_cfg["command_timeout_ms"] * 1e-3,
                     RealClock(cfg["loop"]["spin_us"] * 1e-6), aux_hz=node_cfg["aux_hz"],
                     catch_up=cfg["loop"]["catch_up"])
    try:
        with realtime(cfg["loop"]["rt_priority"]):
            st = node.run(duration, stop=lambda: bool(stopping))
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        transport.close()
        session.close()
    n = st.to_json()
    rt = n["round_trip_us"]
    print(f"valve-node: {st.steps} steps, {st.overruns} overruns, {st.commands} commands, "
          f"{st.bad_commands} bad, {st.timeouts} command timeouts"
          + (f", round trip p50 {rt['p50']:.0f} us p99 {rt['p99']:.0f} us" if rt["n"] else ""))
    if args.json:
        write_json_atomic(args.json, n)
    return 0
