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
    from models.fitting import evaluate, fit_recording
    from models.model import save_model, write_json_atomic
    from models.recording import read_recording

    rec = read_recording(args.recording)
    model = fit_recording(args.model, rec, n=args.n)
    m = evaluate(model, rec.duty_pct, rec.flow_lpm)
    model.meta.update({"mae": m.mae, "rmse": m.rmse, "r": m.r})
    save_model(model, args.output)
    out = {"kind": model.kind, "mae": m.mae, "rmse": m.rmse, "r": m.r, "fit_s": model.meta["fit_s"]}
    if args.json:
        write_json_atomic(args.json, out)
    print(f"{model.kind}: MAE {m.mae:.3f} L/min  RMSE {m.rmse:.3f} L/min  r {m.r:.5f}  fit {out['fit_s']:.2f} s"
          f"  -> {args.output}")
    return 0
