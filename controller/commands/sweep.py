"""A controller tuning sweep: every candidate in closed loop on the simulated valve and its variants, ranked."""
from __future__ import annotations


def add_arguments(p) -> None:
    p.add_argument("--config", default="config/sweep.toml", metavar="SWEEP.toml",
                   help="sweep file (default %(default)s)")
    p.add_argument("-o", "--output", required=True, metavar="SWEEP.csv", help="one row per candidate")
    p.add_argument("--json", default=None, metavar="S.json",
                   help='summary {"candidates","seconds","default":{"params",..},"best":{..}}')
    p.add_argument("--plot", default=None, metavar="P.png",
                   help="Pareto front (IAE against duty TV) and a heatmap over the winning controller's settings")
    p.add_argument("--report", default=None, metavar="DIR", help="Markdown report: default, best, and the plot")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler (e.g. tcp://host:8786); default: a local process pool")
    p.add_argument("--workers", type=int, default=None, metavar="N", help="local processes (default: one per core)")
    p.add_argument("--best-config", default=None, metavar="BEST.toml",
                   help="the best candidate as a run configuration for `valvectl run --config`")


def run(args) -> int:
    from models.atomicfile import save_figure_atomic
    from models.model import write_json_atomic
    from models.recording import InputError

    from controller.sweep import runner
    from controller.sweep.spec import apply, load_sweep, write_run_config

    from controller.commands.outputs import check_outputs

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers: must be positive, got {args.workers}")
    check_outputs(args, files=("output", "json", "plot", "best_config"))
    s = load_sweep(args.config)
    r = runner.run_sweep(s, args.scheduler, args.workers)
    runner.write_csv(r, args.output)
    summ = runner.summary(r)
    if args.json:
        write_json_atomic(args.json, summ)
    if args.best_config:
        best = s.candidates
        cfg = apply(s.run, best.controller[r.best], best.row(r.best))
        write_run_config(cfg, args.best_config, duration_s=s.duration_s)
    if args.plot or args.report:
        from controller.sweep.plot import sweep_plot, winner_heatmap, winner_settings, write_sweep_report

        heat = winner_heatmap(r.table, s.objective, r.best, s.heatmap)
        xy = None
        if heat is not None:
            xy = tuple(r.table[n][r.best] for n in winner_settings(r.table, r.best, s.heatmap))
        fig = sweep_plot(r.table, s.objective, heat=heat, default_index=r.default, best_index=r.best,
                         title=f"{summ['candidates']} candidates x {summ['variants']} plant variants", best_xy=xy)
        if args.plot:
            save_figure_atomic(fig, args.plot, dpi=110)
        if args.report:
            print(f"report -> {write_sweep_report(args.report, summ, s.objective, fig)}")
    d, b = summ["default"], summ["best"]

    def f(v):
        return "-" if v is None else f"{v:.4f}"

    print(f"{summ['candidates']} candidates x {summ['variants']} variants in {summ['seconds']:.1f} s "
          f"({summ['candidates'] / summ['seconds']:.0f} candidates/s) -> {args.output}")
    def figs(x):
        return f"iae {f(x['iae'])} L" + (f", {s.objective} {f(x[s.objective])}" if s.objective != "iae" else "")

    print(f"default {d['params']['controller']}: {figs(d)}")
    print(f"best    {b['params']['controller']}: {figs(b)}  "
          + " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in b["params"].items()
                     if k != "controller"))
    return 0
