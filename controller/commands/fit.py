"""Fit one hysteresis model to a recording and write its model file."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="REC.csv", help="recording (t_s, duty_pct, flow_lpm)")
    p.add_argument("--model", required=True, metavar="KIND",
                   help="pi, pi-asym, preisach, preisach-cont or bouc-wen")
    p.add_argument("--n", type=int, default=None, metavar="N",
                   help="resolution: operators (PI), hysterons per axis (Preisach); kind default if absent")
    p.add_argument("-o", "--output", required=True, metavar="MODEL.json", help="model file to write")
    p.add_argument("--json", default=None, metavar="M.json", help='figures {"kind","mae","rmse","r","fit_s"}')


def run(args) -> int:
    import sys
    import time

    from models.fitting import evaluate, fit_recording
    from models.model import save_model, write_json_atomic
    from models.recording import read_recording
    from controller.commands.outputs import check_outputs

    check_outputs(args, files=("output", "json"), folders=())
    t0 = time.perf_counter()
    tty = sys.stderr.isatty()

    def stage(text: str) -> None:
        if tty:
            sys.stderr.write(f"\r[{time.perf_counter() - t0:6.1f} s] {text:<60}")
            sys.stderr.flush()

    stage(f"reading {args.recording}...")
    rec = read_recording(args.recording)
    stage(f"fitting {args.model} on {len(rec)} rows...")
    model = fit_recording(args.model, rec, n=args.n)
    stage("scoring the fit...")
    m = evaluate(model, rec.duty_pct, rec.flow_lpm)
    if tty:
        sys.stderr.write("\n")
    model.meta.update({"mae": m.mae, "rmse": m.rmse, "r": m.r})
    save_model(model, args.output)
    out = {"kind": model.kind, "mae": m.mae, "rmse": m.rmse, "r": m.r, "fit_s": model.meta["fit_s"]}
    if args.json:
        write_json_atomic(args.json, out)
    print(f"{model.kind}: MAE {m.mae:.3f} L/min  RMSE {m.rmse:.3f} L/min  r {m.r:.5f}  fit {out['fit_s']:.2f} s"
          f"  -> {args.output}")
    return 0
