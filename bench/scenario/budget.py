"""``bench budget``: which error source ate the accuracy? The scenario re-run with one source switched off at a time.

A scenario kind declares its error sources in ``BUDGET`` (``{source: {key: value}}``, the overrides that make that
source perfect - e.g. ``sources.features: perfect``), the metrics to budget in ``BUDGET_METRICS`` and the overrides
that every budget run takes in ``BUDGET_FIXED`` (e.g. no rerun recording). For every variant - all sources real
(``full``), each source perfect in turn, and all perfect (``none``, the floor) - a resumable sweep over the same seeds
runs in ``DIR/<variant>/`` (:mod:`bench.scenario.sweep`; renders are shared through the cache). Then, per metric,
with RMS over seeds::

    budget_<source> = sqrt(max(0, RMS_full^2 - RMS_without_source^2))

the part of the final error that the source explains (errors of independent sources add in quadrature; the sum of
the budgets' squares next to ``RMS_full^2`` shows how far that holds: ``budget_closure_<metric>`` =
``sqrt(sum budget^2 + RMS_none^2) / RMS_full``, 1 when it adds up).

That difference of two mean squares is a noisy estimate of a small share: each term carries the sampling noise of the
large error it is the square of. Where the kind also declares each metric's signed components (``BUDGET_VECTORS``,
e.g. the base's position error as x, y, z), the share is measured directly instead, seed by seed::

    budget_<source> = sqrt(mean over seeds |e_full - e_without_source|^2)

the RMS of the displacement that switching the source off causes in the paired run: with errors that add (``e_full
= e_none + sum of the sources' parts``) it is the source's part, and its square is what the source adds to
``RMS_full^2`` when the parts are independent - the same quantity, without the other sources' noise in it. Where the
sources interact (through an estimator's nonlinear and discrete choices) it is the source's total effect, its part
and its share of every interaction it takes part in (Jansen's estimator of a total sensitivity index, with the
source set perfect instead of redrawn), and the closure exceeds 1 by the interactions counted more than once. The
difference of mean squares stays in ``budget.csv`` beside it (``budget_<metric>_difference``) and is the share of a
metric without components. The primary metric's budgets are reported as
``budget_<source>_<unit>`` (``budget_features_mm`` ...), the others as ``budget_<source>_<metric>``.
``DIR/result.json`` (the result contract), ``budget.csv`` and ``budget.png`` (a bar chart) are written.

The variants run on the same seeds (the kinds draw every random source from a stream of its own, so that switching
one off leaves the others' draws unchanged), and a budget over a handful of seeds is itself uncertain: a paired
bootstrap over the seeds (the same resampled seeds in both variants) gives each budget a 90 % interval,
``budget_<source>_<unit>_lo`` / ``_hi`` (error bars on the plot).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench.errors import ConfigError
from bench.fileio import atomic_save_figure, headless_pyplot
from bench.scenario.results import write_result, write_table_csv


def _rms(values) -> float:
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    return float(np.sqrt(np.mean(v**2))) if len(v) else float("nan")


def run_budget(scenario, seeds: list, out, backend: str = "local", address=None, workers=None,
               fixed: dict | None = None, progress: bool = True, force: bool = False) -> dict:
    """Run (or resume) the budget of ``scenario`` over ``seeds``; returns ``{"result": path, "metrics": {...}}``.

    Every variant's values, the seeds and the worker count are checked before ``out`` is touched; ``out`` is then
    claimed (:func:`bench.fileio.claim_output_dir`, command ``budget``, identity the scenario file's name): a new or
    empty folder or a previous budget of the same scenario (resumed); ``force`` starts a previous budget afresh.
    """
    from bench.config import load_yaml
    from bench.fileio import check_output_dir, claim_output_dir, foreign_entries, record_output_entries
    from bench.scenario.runner import kind_module, load_scenario
    from bench.scenario.sweep import _ray_connect, check_seeds_and_workers, read_runs, run_sweep

    scenario = Path(scenario)
    kind = load_yaml(scenario).get("kind")
    module = kind_module(kind, scenario)
    if not hasattr(module, "BUDGET"):
        raise ConfigError(scenario, "kind", f"scenario kind {kind!r} declares no error sources to budget")
    sources = module.BUDGET
    metrics = module.BUDGET_METRICS
    vectors = getattr(module, "BUDGET_VECTORS", {})
    variants = {"full": {}, **{s: dict(o) for s, o in sources.items()},
                "none": {k: v for o in sources.values() for k, v in o.items()}}
    check_seeds_and_workers(seeds, workers, backend, address)
    every = {**getattr(module, "BUDGET_FIXED", {}), **(fixed or {})}  # the overrides every variant takes
    for overrides in variants.values():  # every variant's values, before anything is created
        load_scenario(scenario, seeds[0], [f"{k}={json.dumps(v)}" for k, v in {**every, **overrides}.items()])
    out = Path(out)
    check_output_dir(out, "budget", force=force, identity=scenario.name)
    # a missing Ray or a cluster that refuses: refused before the folder is made
    started = _ray_connect(address) if backend == "ray" else False
    try:
        before = foreign_entries(out)
        claim_output_dir(out, "budget", force=force, identity=scenario.name)
        rows = {}
        for name, overrides in variants.items():
            if progress:
                print(f"variant {name}: {overrides or 'every source real'}")
            # one render cache for every variant: a source the images do not depend on is not rendered again
            res = run_sweep(scenario, [], seeds, out / name, backend, address, workers, progress=progress,
                            fixed={**every, **overrides}, render_cache=out / ".render_cache")
            rows[name] = read_runs(out / name)  # the variant's finished runs
            if res["errors"] and progress:
                print(f"  {len(res['errors'])} runs failed, e.g. {res['errors'][0]}")
        table, budget_table, result_metrics = budget_from_rows(rows, list(sources), metrics, vectors)
        write_table_csv(out / "variants.csv", table)
        write_table_csv(out / "budget.csv", budget_table)
        plot = _plot(budget_table, metrics, table, out / "budget.png", scenario.stem)
        path = write_result(out, f"budget:{scenario.stem}", int(seeds[0]) if seeds else 0, result_metrics,
                            {"variants": table, "budget": budget_table}, {},
                            {"variants": "variants.csv", "budget": "budget.csv", "plot": Path(plot).name,
                             **{f"sweep_{v}": f"{v}/sweep.sqlite" for v in variants}})
        record_output_entries(out, exclude=before)
        return {"result": str(path), "metrics": result_metrics, "table": budget_table}
    finally:
        if started:
            import ray

            ray.shutdown()


def _pairs(full_rows, rows, value) -> list:
    """``[(value(full row), value(variant row))]`` for the seeds both variants finished (by ``seed``, in seed order,
    so that the bootstrap does not depend on the order runs finished in; by position if the rows carry no seed),
    pairs with a missing value (``value`` returned None) left out."""
    if all("seed" in r for r in full_rows + rows):
        other = {r["seed"]: value(r) for r in rows}
        pairs = [(value(r), other.get(r["seed"])) for r in sorted(full_rows, key=lambda r: r["seed"])]
    else:
        pairs = list(zip(map(value, full_rows), map(value, rows), strict=False))
    return [p for p in pairs if None not in p]


def _finite(r, names):
    """The values of metrics ``names`` in row ``r``, None if any is missing or not finite."""
    v = [r["metrics"].get(n) for n in names]
    return None if any(x is None or not np.isfinite(x) for x in v) else v


def _paired(full_rows, rows, m) -> np.ndarray:
    """``(k, 2)`` values of metric ``m``, paired by :func:`_pairs`."""
    return np.array(_pairs(full_rows, rows, lambda r: _finite(r, [m])), dtype=float).reshape(-1, 2)


def _paired_vectors(full_rows, rows, names) -> np.ndarray:
    """``(k, 2, d)`` signed components ``names`` of the full run and the variant, paired by :func:`_pairs` (a seed
    with any component missing or not finite left out)."""
    return np.array(_pairs(full_rows, rows, lambda r: _finite(r, names)), dtype=float).reshape(-1, 2, len(names))


def _bootstrap(values, statistic, n_boot=2000, seed=0) -> tuple:
    """90 % bootstrap interval of ``statistic(values[idx])`` over the seeds (the rows of ``values``)."""
    if len(values) < 2:
        return float("nan"), float("nan")
    idx = np.random.default_rng(seed).integers(0, len(values), (n_boot, len(values)))
    b = statistic(values[idx])
    return float(np.percentile(b, 5)), float(np.percentile(b, 95))


def _difference_share(pairs) -> np.ndarray:
    """``sqrt(max(0, RMS_full^2 - RMS_without^2))`` of ``(..., k, 2)`` paired values."""
    ms = np.mean(pairs**2, axis=-2)
    return np.sqrt(np.clip(ms[..., 0] - ms[..., 1], 0.0, None))


def _displacement_share(vectors) -> np.ndarray:
    """``sqrt(mean |e_full - e_without|^2)`` of ``(..., k, 2, d)`` paired error vectors."""
    d = vectors[..., 0, :] - vectors[..., 1, :]
    return np.sqrt(np.mean(np.sum(d**2, axis=-1), axis=-1))


def budget_from_rows(rows: dict, sources: list, metrics: list, vectors: dict | None = None) -> tuple:
    """The budget from finished runs: ``rows = {variant: [{"seed": s, "metrics": {...}}, ...]}`` with variants
    ``full``, each source and ``none``; ``vectors`` maps a metric to the names of its signed components (the paired
    displacement share, where every variant's rows carry them; see the module docstring); returns ``(variants table,
    budget table, result metrics)``."""
    vectors = vectors or {}
    variants = ["full", *sources, "none"]
    table = {"variant": variants, "runs": [len(rows[v]) for v in variants],
             **{f"rms_{m}": [_rms(r["metrics"].get(m) for r in rows[v]) for v in variants] for m in metrics}}
    result_metrics = {}
    primary, unit = metrics[0], metrics[0].rsplit("_", 1)[-1]
    budget_table = {"source": list(sources)}
    for m in metrics:
        full = table[f"rms_{m}"][0]
        col, lo, hi, diff, method = [], [], [], [], []
        for i, s in enumerate(sources, start=1):
            without = table[f"rms_{m}"][i]
            ok = np.isfinite(full) and np.isfinite(without)
            diff.append(float(np.sqrt(max(0.0, full**2 - without**2))) if ok else float("nan"))
            vec = _paired_vectors(rows["full"], rows[s], vectors[m]) if m in vectors else np.zeros((0, 2, 3))
            pairs = _paired(rows["full"], rows[s], m)
            # the paired displacement - the share measured seed by seed - where every paired seed has the components
            # (runs of an earlier version, without them, leave the whole share to the difference: never a mixture)
            if len(vec) >= 2 and len(vec) == len(pairs):
                col.append(float(_displacement_share(vec)))
                a, b = _bootstrap(vec, _displacement_share)
                method.append("paired displacement")
            else:
                col.append(diff[-1])
                a, b = _bootstrap(pairs, _difference_share)
                method.append("difference of mean squares")
            lo.append(a)
            hi.append(b)
            name = f"budget_{s}_{unit}" if m == primary else f"budget_{s}_{m}"
            result_metrics[name], result_metrics[f"{name}_lo"], result_metrics[f"{name}_hi"] = col[-1], a, b
        budget_table[f"budget_{m}"] = col
        budget_table[f"budget_{m}_lo"], budget_table[f"budget_{m}_hi"] = lo, hi
        budget_table[f"budget_{m}_difference"], budget_table[f"budget_{m}_method"] = diff, method
        result_metrics[f"rms_full_{m}"] = full
        result_metrics[f"rms_floor_{m}"] = table[f"rms_{m}"][-1]
        result_metrics[f"budget_quadrature_sum_{m}"] = float(np.sqrt(np.nansum(np.square(col))))
        # does it add up: the shares and the floor in quadrature against the full RMS (1 = closes exactly)
        floor = table[f"rms_{m}"][-1]
        result_metrics[f"budget_closure_{m}"] = float(np.sqrt(np.nansum(np.square(col)) + (floor**2 if np.isfinite(
            floor) else 0.0)) / full) if np.isfinite(full) and full > 0 else float("nan")
    return table, budget_table, result_metrics


def _plot(budget_table, metrics, table, path, title) -> str:
    plt = headless_pyplot()

    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 4.0), squeeze=False)
    for ax, m in zip(axes[0], metrics, strict=True):
        vals, lo, hi = (np.array(budget_table[f"budget_{m}{s}"], dtype=float) for s in ("", "_lo", "_hi"))
        err = np.nan_to_num(np.stack([np.clip(vals - lo, 0, None), np.clip(hi - vals, 0, None)]))
        how = sorted(set(budget_table[f"budget_{m}_method"]))
        ax.bar(budget_table["source"], vals, color="tab:blue", yerr=err, capsize=4, ecolor="0.3",
               label=f"share ({' / '.join(how)}), 90 % bootstrap over seeds")
        if how != ["difference of mean squares"]:
            ax.plot(budget_table["source"], budget_table[f"budget_{m}_difference"], "o", mfc="none", color="tab:red",
                    label="difference of mean squares")
        full = table[f"rms_{m}"][0]
        ax.axhline(full, color="k", lw=1, ls="--", label="RMS, every source real")
        ax.set_title(f"{m}: RMS {full:.3g}", fontsize=9)
        ax.set_ylabel(f"share of {m} (quadrature)")
        ax.tick_params(axis="x", rotation=30)
        ax.grid(alpha=0.3, axis="y")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.suptitle(f"error budget: {title}")
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    atomic_save_figure(fig, path, dpi=110)
    return str(path)
