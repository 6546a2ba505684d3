"""Paper Table 1 on a recording (every model kind), plus the inverse PI check."""
from __future__ import annotations

import sys


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="REC.csv", help="recording to fit on (in-sample figures)")
    p.add_argument("--validate", default=None, metavar="REC2.csv", help="recording for validation only, never fitted")
    p.add_argument("--json", required=True, metavar="OUT.json", help="figures, DESIGN.md layout")
    p.add_argument("--plot", default=None, metavar="OUT.png",
                   help="Fig. 3 per model, residuals by branch, validation and the inverse checks")
    p.add_argument("--report", default=None, metavar="DIR", help="Markdown report with Table 1 and the figure")


def run(args) -> int:
    from models.compare import compare_response, write_compare_report
    from models.atomicfile import save_figure_atomic
    from models.model import write_json_atomic
    from models.recording import read_recording

    from controller.commands.outputs import check_outputs

    check_outputs(args, files=("json", "plot"))
    rec = read_recording(args.recording)
    val = read_recording(args.validate) if args.validate else None
    if val is not None:  # a validation of one row or of a constant duty has no r, no error to speak of
        from models.recording import check_fittable

        check_fittable(val, purpose="validate a model")

    def progress(kind: str) -> None:
        if sys.stderr.isatty():
            sys.stderr.write(f"fitting {kind}...\n")

    comparison = compare_response(rec, val, progress=progress)
    write_json_atomic(args.json, comparison.to_json())
    print(comparison.table())
    if args.plot:
        save_figure_atomic(comparison.plot(), args.plot, dpi=110)
        print(f"plot -> {args.plot}")
    if args.report:
        print(f"report -> {write_compare_report(comparison, args.report)}")
    return 0
