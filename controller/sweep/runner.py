"""Run a sweep: group and chunk the candidates, simulate the chunks where asked, rank, and write the results.

Candidates are grouped by what one batch must share (controller word,
feedforward model, preview) and cut into chunks of at most ``chunk_loops``
loops (candidates x plant variants); each chunk builds its candidates'
controllers with the run's own builder
(:func:`controller.config.controller_params`, one candidate at a time,
then joined into one batch) and simulates them with
:mod:`controller.sweep.simulate`.
"""
from __future__ import annotations

import csv
import math
import os
import time
from dataclasses import dataclass

import numpy as np

from . import metrics, simulate, spec as sp
from .distributed import LocalPool, default_workers, map_chunks

MARGIN_NAMES = ("gain_margin_db", "phase_margin_deg")
#: Batches per pool worker at least (when ``chunk_loops`` allows): the last ones are small.
CHUNKS_PER_WORKER = 8


@dataclass(frozen=True)
class Chunk:
    """One batch of candidates of one structure, picklable for a process pool or a Dask worker.

    ``params``: each candidate's ControllerParams (batch of one), joined and
    repeated over the plant variants by the worker.
    """

    params: list
    plants: list
    ref_lpm: np.ndarray
    rate_hz: float
    preview_steps: np.ndarray  # per candidate
    seed: int


def build_one(run, word: str, row: dict, models: dict):
    """Candidate's ControllerParams (batch of one) by the run's builder, and its preview in seconds."""
    from controller.config import controller_params, preview_s

    cfg = sp.apply(run, word, row)
    return controller_params(cfg, word, models[cfg.resolve(cfg[""]["model"])]), preview_s(cfg, "profile")


def structure(x):
    """What must agree for candidates to share a batch: words, flags, present parts, array widths."""
    import dataclasses

    if dataclasses.is_dataclass(x):
        return tuple((f.name, structure(getattr(x, f.name))) for f in dataclasses.fields(x))
    if isinstance(x, np.ndarray):
        return (x.dtype.str, x.shape[1:])
    return x if x is None or isinstance(x, (str, bool, int)) else type(x).__name__


def simulate_chunk(c: Chunk) -> dict:
    """Figures of the chunk's candidates, arrays (C, V)."""
    with one_blas_thread():
        return _simulate(c)


def _simulate(c: Chunk) -> dict:
    V = len(c.plants)
    params = simulate.stack_params([p for p in c.params for _ in range(V)])
    r = simulate.response(params, c.plants, c.ref_lpm, c.rate_hz, c.seed, np.repeat(c.preview_steps, V))
    return simulate.figures(r, V)


@dataclass
class SweepResult:
    """The table and what the summary needs."""

    spec: sp.SweepSpec
    table: dict  # column -> list (parameters, figures, worst case, margins)
    columns: list
    seconds: float
    best: int
    default: int = 0


def load_models(s: sp.SweepSpec) -> dict:
    """Every feedforward model file the candidates name, loaded once: resolved path -> FittedModel."""
    from models.model import load_model
    from models.recording import InputError

    models = {}
    for i in range(len(s.candidates)):
        path = s.run.resolve(sp.setting(s.run, s.candidates.row(i), "model"))
        if path not in models:
            try:
                models[path] = load_model(path)
            except InputError as exc:
                raise InputError(f"{s.path}: candidate {i} model: {exc}") from None
    return models


@dataclass(frozen=True)
class Build:
    """Candidates to build, picklable: the run, ``(word, settings)`` pairs and the models."""

    run: object
    rows: list
    models: dict


def one_blas_thread():
    """BLAS on one thread: the pool already runs a process per core, and on the tiny matrices of a
    Kalman design or a margin computation BLAS threads only wait for each other (10x slower on a busy machine)."""
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, "blas")


def build_many(b: Build) -> list:
    """``[(ControllerParams, preview_s)]`` of a block of candidates (a Kalman design costs about a ms)."""
    with one_blas_thread():
        return [build_one(b.run, w, r, b.models) for w, r in b.rows]


@dataclass(frozen=True)
class Job:
    """A block of candidates to build and simulate on every plant variant, picklable for a Dask worker."""

    build: Build
    plants: list
    ref_lpm: np.ndarray
    seed: int


def run_job(j: Job) -> dict:
    """Figures (C, V) of the job's candidates, in its order: each built by the run's builder where the
    job runs, the built ones grouped by :func:`structure` and each group simulated as one batch."""
    with one_blas_thread():
        return _job(j)


def _job(j: Job) -> dict:
    run = j.build.run
    rate = run["loop"]["rate_hz"]
    built = [build_one(run, w, r, j.build.models) for w, r in j.build.rows]
    groups = {}
    for i, (p, _) in enumerate(built):
        groups.setdefault(structure(p), []).append(i)
    out = {k: np.empty((len(built), len(j.plants))) for k in metrics.NAMES}
    for idx in groups.values():
        res = _simulate(Chunk([built[i][0] for i in idx], j.plants, j.ref_lpm, rate,
                              np.array([int(round(built[i][1] * rate)) for i in idx]), j.seed))
        for k in metrics.NAMES:
            out[k][idx] = res[k]
    return out


#: The jobs of the sweep under way, for the local pool's forked workers (they inherit them: no pickling).
_JOBS: list = []


def _run_local(i: int) -> dict:
    if not _worker_blas():
        return run_job(_JOBS[i])
    return _job(_JOBS[i])


_BLAS_SET = False
#: The process that runs the sweep (set before its pool forks).
_PARENT = None


def _worker_blas() -> bool:
    """In a local pool's worker, BLAS on one thread, set once for its life (:func:`one_blas_thread`
    costs about 5 ms a call; the worker is ours alone, nothing to restore); False in the sweep's process."""
    global _BLAS_SET
    if os.getpid() == _PARENT:
        return False
    if not _BLAS_SET:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, "blas")
        _BLAS_SET = True
    return True


#: Relative cost of a candidate of each controller word (CPU seconds per candidate of the default sweep's
#: jobs: pid 4.4-5.0 ms, ff+pid 5.6-12 ms (by model), ff+kf 11-14 ms, ff 13 ms), to start the costliest first.
WORD_COST = {"pid": 0.4, "ff+pid": 0.8, "ff+kf": 1.0, "ff": 1.0}


def jobs_of(s: sp.SweepSpec, plants: list, ref: np.ndarray, models: dict, workers: int | None = None):
    """``(jobs, candidate indices per job)``: candidates of one controller word and model together (a
    batch's candidates must share a structure: the job checks it again once built), costliest first."""
    run, cands = s.run, s.candidates
    n_workers = workers or default_workers()
    groups = {}
    for i in range(len(cands)):
        word, row = cands.controller[i], cands.row(i)
        groups.setdefault((word, run.resolve(sp.setting(run, row, "model"))), []).append(i)
    # at most chunk_loops loops a batch, and enough batches that the pool's workers finish together
    # (a word's loop costs up to 4x another's: few large batches leave one worker running alone)
    per = max(1, min(s.chunk_loops // len(plants), math.ceil(len(cands) / (CHUNKS_PER_WORKER * n_workers))))
    parts = [(WORD_COST.get(key[0], 1.0) * len(idx[a:a + per]), idx[a:a + per])
             for key, idx in groups.items() for a in range(0, len(idx), per)]
    parts.sort(key=lambda x: x[0], reverse=True)  # costliest first: the pool's workers finish together
    parts = [p for _, p in parts]
    jobs = [Job(Build(run, [(cands.controller[i], cands.row(i)) for i in part], models), plants, ref, run[""]["seed"])
            for part in parts]
    return jobs, parts


_LOADED = False


def load_kernels(s: sp.SweepSpec) -> None:
    """The sweep's compiled kernels loaded from numba's cache into this process, and what building a candidate
    imports, once: a 3-step closed loop of the default candidate on the run's valve (each kernel has one
    signature, whatever the controller word). A local pool's workers, forked after, inherit them; else each
    loaded the kernel itself (0.3 s of CPU each) inside the timed span."""
    global _LOADED
    if _LOADED:
        return
    from controller.config import controller_params
    from controller.laws import control
    from models.model import load_model
    from plant_sim.plant import BatchPlant, load_plant

    run = s.run
    cfg = sp.apply(run, s.candidates.controller[0], s.candidates.row(0))
    with one_blas_thread():
        p = controller_params(cfg, cfg[""]["controller"], load_model(cfg.resolve(cfg[""]["model"])))
    valve = load_plant(run.resolve(run[""]["plant_config"]), effects=run["effects"])
    rate = run["loop"]["rate_hz"]
    simulate.closed_loop(control.repeat(p, 2), BatchPlant([valve, valve], rate), np.full(3, 10.0), rate, 1)
    _LOADED = True


def run_sweep(s: sp.SweepSpec, scheduler: str | None = None, workers: int | None = None) -> SweepResult:
    """Simulate every candidate on every variant, rank, and compute the top candidates' margins.

    A local pool is forked once, at the start: its workers build and simulate the jobs (which they
    inherit), then compute the margins, while this process writes the parameter columns and
    linearizes the valve.

    :attr:`SweepResult.seconds` times the work itself: python-control (the margins) is imported
    and, for a local pool, the compiled kernels are loaded from numba's cache (:func:`load_kernels`)
    before the clock starts, as every ``*_s`` figure leaves imports and compilation out.
    """
    global _JOBS, _SWEEP, _PARENT
    import multiprocessing as mp

    if s.margins_top:
        import control  # noqa: F401
    local = not scheduler and "fork" in mp.get_all_start_methods()
    if not scheduler:
        load_kernels(s)
    t0 = time.perf_counter()
    plants = sp.plants(s.run, s.variants, s.path)
    ref = sp.reference(s.run, s.duration_s)
    models = load_models(s)
    jobs, index = jobs_of(s, plants, ref, models, workers)
    params, op = [], []

    def during():  # in this process while the workers run
        params.append(_parameter_columns(s))
        if s.margins_top:
            op.append(_operating_point(s, plants[0], ref))

    _JOBS, _SWEEP = (jobs, (s, plants[0], ref, models)) if local else ([], None)
    _PARENT = os.getpid()
    try:
        with LocalPool() as pool:
            results = map_chunks(_run_local if local else run_job, range(len(jobs)) if local else jobs,
                                 [len(i) for i in index], scheduler, workers, during=during, pool=pool)
            n, V = len(s.candidates), len(plants)
            fig = {k: np.full((n, V), np.nan) for k in metrics.NAMES}
            for idx, res in zip(index, results):
                for k in metrics.NAMES:
                    fig[k][idx] = res[k]
            table, columns = params[0]
            for k in metrics.NAMES:
                table[k] = fig[k][:, 0]
                columns.append(k)
            if V > 1:
                for k, v in metrics.worst_case(fig).items():
                    table[f"worst_{k}"] = v
                    columns.append(f"worst_{k}")
            obj = np.asarray(table[s.objective], dtype=np.float64)
            best = int(np.nanargmin(np.where(np.isfinite(obj), obj, np.nan))) if np.isfinite(obj).any() else 0
            if s.margins_top:
                top = [int(i) for i in np.argsort(np.where(np.isfinite(obj), obj, np.inf))[:s.margins_top]]
                table.update(_top_margins(s, models, top, op[0], workers, local, pool))
                columns += list(MARGIN_NAMES)
    finally:
        _JOBS, _SWEEP = [], None
    return SweepResult(s, table, columns, time.perf_counter() - t0, best)


#: The sweep under way ``(spec, nominal plant, reference, models)``, for the local pool's margins.
_SWEEP = None


def _parameter_columns(s: sp.SweepSpec):
    cands = s.candidates
    names = list(cands.settings)
    eff = [sp.effective(s.run, cands.controller[i], cands.row(i), names) for i in range(len(cands))]
    table = {"controller": list(cands.controller)}
    for nm in names:
        table[nm] = [e[nm] for e in eff]
    return table, ["controller", *names]


def _margin_flow(s: sp.SweepSpec, ref) -> float:
    return s.margins_flow_lpm if s.margins_flow_lpm is not None else float(np.max(ref))


def _operating_point(s: sp.SweepSpec, plant, ref):
    from . import margins as mg

    return mg.operating_point(plant, _margin_flow(s, ref), s.run["loop"]["rate_hz"])


def _model_sources(s: sp.SweepSpec, top) -> dict:
    """Model path -> the first ``ff+kf`` candidate of ``top`` on it: whose forward model's slope every
    ``ff+kf`` candidate on that path uses (:func:`controller.sweep.margins.model_gain`)."""
    run, out = s.run, {}
    for i in top:
        if s.candidates.controller[i] == "ff+kf":
            out.setdefault(run.resolve(sp.setting(run, s.candidates.row(i), "model")), i)
    return out


def _top_margins(s: sp.SweepSpec, models: dict, top: list, op, workers, local: bool, pool) -> dict:
    """Margins columns (None but for ``top``): on the local pool's workers, split by model path, else here."""
    sources = _model_sources(s, top)
    n = workers or default_workers()
    if not local or n <= 1 or len(top) <= 1:
        with one_blas_thread():  # a margin costs milliseconds
            return _margins(s, models, top, op, sources)
    # the candidates of one model path together (its slope is computed once), costliest groups first
    run, groups = s.run, {}
    for i in top:
        word = s.candidates.controller[i]
        key = run.resolve(sp.setting(run, s.candidates.row(i), "model")) if word == "ff+kf" else i
        groups.setdefault(key, []).append(i)
    parts = [[] for _ in range(min(n, len(top)))]
    cost = [0.0] * len(parts)
    for g in sorted(groups.values(), key=lambda g: -(len(g) + (1.2 if s.candidates.controller[g[0]] == "ff+kf" else 0))):
        w = int(np.argmin(cost))
        parts[w] += g
        cost[w] += len(g) + (1.2 if s.candidates.controller[g[0]] == "ff+kf" else 0)
    parts = [p for p in parts if p]
    out = {k: [None] * len(s.candidates) for k in MARGIN_NAMES}
    for res in map_chunks(_margins_local, [(p, op, sources) for p in parts], [len(p) for p in parts], None,
                          workers, desc="margins", pool=pool):
        for k in MARGIN_NAMES:
            for i, v in res[k].items():
                out[k][i] = v
    return out


def _margins_local(part) -> dict:
    top, op, sources = part
    s, _, _, models = _SWEEP
    if _worker_blas():
        full = _margins(s, models, top, op, sources)
    else:
        with one_blas_thread():
            full = _margins(s, models, top, op, sources)
    return {k: {i: full[k][i] for i in top} for k in MARGIN_NAMES}


def _margins(s: sp.SweepSpec, models: dict, top, op, sources: dict) -> dict:
    """Margins of the candidates ``top``; an ``ff+kf`` one with the model slope of ``sources[its path]``."""
    from . import margins as mg

    run = s.run
    out = {k: [None] * len(s.candidates) for k in MARGIN_NAMES}
    k_model = {}
    for i in top:
        word, row = s.candidates.controller[i], s.candidates.row(i)
        path = run.resolve(sp.setting(run, row, "model"))
        p, _ = build_one(run, word, row, models)
        if word == "ff+kf" and path not in k_model:
            j = sources[path]
            pj = p if j == i else build_one(run, s.candidates.controller[j], s.candidates.row(j), models)[0]
            k_model[path] = mg.model_gain(pj.forward, 0, op.flow_lpm)
        m = mg.loop_margins(p, 0, op, k_model.get(path) if word == "ff+kf" else None)
        out["gain_margin_db"][i], out["phase_margin_deg"][i] = m.gain_margin_db, m.phase_margin_deg
    return out


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, str):
        return v
    v = float(v)
    if math.isnan(v):
        return ""
    return repr(v) if math.isinf(v) else format(v, ".6g")


def write_csv(r: SweepResult, path: str) -> None:
    """SWEEP.csv: one row per candidate, parameters then figures (DESIGN.md), written atomically."""
    from models.atomicfile import atomic_open

    with atomic_open(path, newline="") as fh:
        w = csv.writer(fh)
        w.writerow(r.columns)
        for i in range(len(r.table["controller"])):
            w.writerow([_cell(r.table[c][i]) for c in r.columns])


def _json_number(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def figure_columns(r: SweepResult) -> list:
    """The columns after the parameters: figures, worst case, margins."""
    return [c for c in r.columns if c in metrics.NAMES or c.startswith("worst_") or c in MARGIN_NAMES]


def candidate_summary(r: SweepResult, i: int) -> dict:
    """``{"params": {...}, "iae", ...}`` of candidate ``i`` (settings that do not apply and non-finite figures: left out / null)."""
    figs = figure_columns(r)
    params = {c: r.table[c][i] for c in r.columns if c not in figs and r.table[c][i] is not None}
    return {"params": params, **{c: _json_number(r.table[c][i]) for c in figs}}


def summary(r: SweepResult) -> dict:
    """S.json of DESIGN.md: ``{"candidates", "seconds", "default", "best"}`` plus the objective and variants."""
    return {
        "candidates": len(r.table["controller"]),
        "seconds": r.seconds,
        "objective": r.spec.objective,
        "variants": len(r.spec.variants),
        "default": candidate_summary(r, r.default),
        "best": candidate_summary(r, r.best),
    }
