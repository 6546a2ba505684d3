"""Find the physics a simulation leaves out: locate the mismatch, name the effect, model it, show the fit improve."""
from __future__ import annotations

import sys


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="REC.csv", help="recording (t_s, duty_pct, flow_lpm; supply_bar, coil_temp_c used)")
    p.add_argument("--model", default=None, metavar="MODEL.json",
                   help="the simulation to hold the recording against (default: the paper's PI, n = 50, "
                        "fitted on the recording's training rows)")
    p.add_argument("--config", default=None, metavar="RUN.toml",
                   help="for a closed-loop run recording (valvectl run --record): hold it against the model "
                        "its feedforward used, the run configuration's model file (instead of --model)")
    p.add_argument("--json", required=True, metavar="D.json", help='{"baseline", "findings", "model"}')
    p.add_argument("--predictions", default=None, metavar="P.csv",
                   help="t_s, flow_lpm, baseline_lpm, augmented_lpm, holdout per recording row")
    p.add_argument("--report", default=None, metavar="DIR", help="Markdown report with PNG plots")


def run(args) -> int:
    from controller.commands.outputs import check_outputs
    from models.diagnose import diagnose_response
    from models.diagnose.report import write_json, write_predictions, write_report
    from models.model import load_model
    from models.recording import check_fittable, read_recording

    from models.recording import InputError

    if args.model and args.config:  # one would be silently ignored: the simulation to hold against is one
        raise InputError(f"--model {args.model} and --config {args.config}: give one (--config names its own model)")
    check_outputs(args, files=("json", "predictions"))
    rec = read_recording(args.recording)
    check_fittable(rec)
    model_path = args.model
    if args.config:
        from controller.config import load_run_config

        cfg = load_run_config(args.config)
        model_path = cfg.resolve(cfg[""]["model"])
    model = load_model(model_path) if model_path else None
    progress = None
    if sys.stderr.isatty():
        def progress(word):
            sys.stderr.write(f"\rtesting {word:<24}")
            sys.stderr.flush()
    diag = diagnose_response(rec, model, progress=progress)
    if progress:
        sys.stderr.write("\r" + " " * 40 + "\r")
    write_json(diag, args.json)
    if args.predictions:
        write_predictions(diag, args.predictions)
    if args.report:
        write_report(diag, args.report, source=args.recording)
    names = ", ".join(f"{f.effect} ({f.holdout_rmse_before:.3f} -> {f.holdout_rmse_after:.3f} L/min)"
                      for f in diag.findings) or "none"
    print(f"baseline RMSE {diag.baseline.rmse:.3f} L/min r {diag.baseline.r:.5f}; findings: {names} -> {args.json}")
    return 0
