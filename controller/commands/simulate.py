"""Make a recording from the simulated valve (plant_sim), with any effects switched on."""
from __future__ import annotations

import sys

#: Columns of the recording (DESIGN.md, Recordings).
COLUMNS = ("t_s", "duty_pct", "flow_lpm", "supply_bar", "coil_temp_c")
#: Rows per chunk when progress is shown (chunks chain exactly: the same recording as one call).
CHUNK = 200_000
#: Most rows a simulated recording may have: the CSV is written at ~0.1-0.2 M rows/s, so 2 M rows (5.5 h at
#: 100 Hz, 33 min at 1 kHz) take seconds; 1e8 (what a protocol may sample) took minutes and gigabytes.
MAX_ROWS = 2_000_000


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


def simulate_with_progress(params, rate_hz: float, seed: int, duty):
    """:meth:`plant_sim.plant.Plant.simulate` in chunks with a progress bar on stderr (same recording)."""
    import numpy as np
    from tqdm import tqdm

    from plant_sim.plant import BatchPlant

    plant = BatchPlant([params], rate_hz, [seed])
    state = plant.init(duty[0])
    parts = []
    with tqdm(total=len(duty), unit=" rows", unit_scale=True, desc="simulate", file=sys.stderr) as bar:
        for i in range(0, len(duty), CHUNK):
            state, c = plant.run(state, duty[None, i:i + CHUNK])
            parts.append(c)
            bar.update(c["flow_lpm"].shape[1])
    cols = {k: np.concatenate([c[k][0] for c in parts]) for k in parts[0]}
    return {"t_s": np.arange(len(duty)) / plant.rate_hz, "duty_pct": duty, **cols}


def run(args) -> int:
    from models.recording import InputError, write_recording
    from plant_sim.effects import parse_effect
    from plant_sim.plant import Plant, load_plant
    from controller.commands.outputs import check_outputs
    from plant_sim.protocols import protocol

    check_outputs(args, files=("output",), folders=())
    if not 0 <= args.seed < 2**63:
        raise InputError(f"--seed: must be within 0..2**63-1 (got {args.seed})")
    effects = dict(parse_effect(text) for text in args.effect)
    params = load_plant(args.plant, effects)
    if args.duration is not None and args.duration * args.rate > MAX_ROWS:  # before the protocol is sampled
        raise InputError(f"--duration: {args.duration:g} s at {args.rate:g} Hz is {args.duration * args.rate:.3g} "
                         f"rows, more than the {MAX_ROWS:.0e} a simulated recording may have")
    duty = protocol(args.protocol, args.rate, args.duration, seed=args.seed)
    if len(duty) > MAX_ROWS:  # a protocol's own length, or a protocol file's span
        raise InputError(f"--protocol {args.protocol}: {len(duty)} rows at {args.rate:g} Hz, more than the "
                         f"{MAX_ROWS:.0e} a simulated recording may have (give --duration or a lower --rate)")
    if sys.stderr.isatty() and len(duty) > CHUNK:
        cols = simulate_with_progress(params, args.rate, args.seed, duty)
    else:
        cols = Plant(params, args.rate, seed=args.seed).simulate(duty)
    try:
        write_recording(args.output, {c: cols[c] for c in COLUMNS})
    except OSError as exc:
        raise InputError(f"-o {args.output}: cannot write ({exc.strerror})") from None
    on = ", ".join(f"{k}={v:g}" for k, v in params.effects.items()) or "none"
    print(f"simulate: {len(duty)} rows at {args.rate:g} Hz, protocol {args.protocol}, effects {on} -> {args.output}")
    return 0
