"""Make a recording from the simulated valve (plant_sim), with any effects switched on."""
from __future__ import annotations

#: Columns of the recording (DESIGN.md, Recordings).
COLUMNS = ("t_s", "duty_pct", "flow_lpm", "supply_bar", "coil_temp_c")


def add_arguments(p) -> None:
    p.add_argument("--plant", default="config/plant.toml", metavar="PLANT.toml",
                   help="plant file: forward model, sensor, physics, default effects (default: %(default)s)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                   help="switch an effect on (repeatable): asymmetric_hysteresis, coil_heating, supply_pressure, "
                        "valve_dynamics, transport_delay, dead_zone, saturation, creep, sensor_offset; "
                        "units as in DESIGN.md; NAME alone takes the default magnitude; 0 = off")
    p.add_argument("--protocol", default="paper_identification", metavar="NAME/FILE",
                   help="duty protocol: paper_identification, steps, ramps, random_holds, sines, "
                        "or a CSV file with t_s,duty_pct (default: %(default)s)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="seconds (default: the protocol's own length)")
    p.add_argument("--seed", type=int, default=0, metavar="K", help="noise seed (and random protocols'); default 0")
    p.add_argument("--rate", type=float, default=100.0, metavar="HZ", help="sample and step rate (default: %(default)s)")
    p.add_argument("-o", "--output", required=True, metavar="REC.csv", help="recording to write")


def run(args) -> int:
    from models.recording import InputError, write_recording
    from plant_sim.effects import parse_effect
    from plant_sim.plant import Plant, load_plant
    from plant_sim.protocols import protocol

    effects = dict(parse_effect(text) for text in args.effect)
    params = load_plant(args.plant, effects)
    duty = protocol(args.protocol, args.rate, args.duration, seed=args.seed)
    cols = Plant(params, args.rate, seed=args.seed).simulate(duty)
    try:
        write_recording(args.output, {c: cols[c] for c in COLUMNS})
    except OSError as exc:
        raise InputError(f"-o {args.output}: cannot write ({exc.strerror})") from None
    on = ", ".join(f"{k}={v:g}" for k, v in params.effects.items()) or "none"
    print(f"simulate: {len(duty)} rows at {args.rate:g} Hz, protocol {args.protocol}, effects {on} -> {args.output}")
    return 0
