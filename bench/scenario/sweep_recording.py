"""``sweep.rrd``, the rerun recording of a ``bench sweep``: every metric's median over the seeds against the swept key.

Entities: ``metrics/<metric>`` (or ``metrics/<metric>/<k2>=<v2>/...`` when more than one key is swept: one line per
value of the other keys) - the median over the seeds of each grid point, on a sequence timeline named for the first
swept key (its value when every value is an integer, else ``<key> (grid index)`` with the value itself logged as
``sweep/value``); ``summary`` (markdown: the grid, the runs per point).

The blueprint (:func:`blueprint`) opens on tab **metrics**: one plot per metric against the swept key, the metric's
bound (``x_bound_y`` beside ``x_err_y``, :func:`bench.scenario.sweep._bound_pairs`) in the same plot; timings
(``*_s``) in tab **timings**; the summary in tab **summary**. Application id ``sweep: <scenario>``, recording name
``sweep: <scenario> over <keys>``.
"""

from __future__ import annotations

from pathlib import Path

from bench.scenario.recording import Recording

BLUE = (60, 120, 230)
ORANGE = (240, 150, 30)


def timeline_name(key: str, xs) -> str:
    """The timeline of the swept key: the key itself when its values are integers, else ``<key> (grid index)``."""
    return key if all(float(v).is_integer() for v in xs) else f"{key} (grid index)"


def record_sweep(path, table: dict, keys: list, metrics: list, bounds: list, scenario: str = "") -> Path:
    """Write ``sweep.rrd`` (module docstring); returns its path.

    Parameters
    ----------
    path : path-like
    table : dict
        The sweep's summary table (:func:`bench.scenario.sweep.summarise`): ``table[key]`` the grid values,
        ``table["<metric>_median"]``, ``table["runs"]``.
    keys : list of str
        The swept keys; the first is the plots' axis.
    metrics : list of str
    bounds : list of (str, str)
        ``(error metric, its bound)`` pairs drawn in one plot.
    scenario : str
        The scenario's name (application id and recording name).
    """
    key = keys[0]
    xs = table[key]
    tl = timeline_name(key, xs)
    integer = tl == key
    others = list(zip(*(table[k] for k in keys[1:]), strict=True)) if len(keys) > 1 else [()] * len(xs)
    label = scenario or Path(path).parent.name
    path = Path(path)
    with Recording(path, f"sweep: {label}", f"sweep-{path.parent.name}",
                   name=f"sweep: {label} over {', '.join(keys)}") as rec:
        rows = "\n".join(f"| {' | '.join(str(table[k][i]) for k in keys)} | {table['runs'][i]} |"
                         for i in range(len(xs)))
        rec.text("summary", f"# sweep of {label} over {', '.join(keys)}\n\nThe median over the seeds of every "
                            f"metric at each grid point, against `{key}` (timeline `{tl}`"
                            + ("" if integer else "; the value is logged as `sweep/value`") + ").\n\n"
                            f"| {' | '.join(keys)} | runs |\n|{'---|' * (len(keys) + 1)}\n{rows}\n")
        if len(keys) == 1:  # one line per plot: the metric blue, its bound orange
            bound_of = dict(bounds)
            for m in metrics:
                if m in bound_of.values():
                    continue
                rec.stream.log(f"metrics/{m}", rec.rr.SeriesLines(colors=[BLUE], widths=[2.0], names=[m]),
                               static=True)
                if m in bound_of:
                    rec.stream.log(f"metrics/{bound_of[m]}", rec.rr.SeriesLines(
                        colors=[ORANGE], widths=[2.0], names=[bound_of[m]]), static=True)
        for i, (x, other) in enumerate(zip(xs, others, strict=True)):
            rec.set_time(tl, int(x) if integer else i)
            if not integer:
                rec.scalar("sweep/value", x)
            suffix = "/".join(f"{k}={v}" for k, v in zip(keys[1:], other, strict=True))
            for m in metrics:
                rec.scalar(f"metrics/{m}" + (f"/{suffix}" if suffix else ""), table[f"{m}_median"][i])
        rec.blueprint(blueprint(key, tl, metrics, bounds, integer))
    return path


def blueprint(key: str, timeline: str, metrics: list, bounds: list, integer: bool = True):
    """One plot per metric (with its bound) against the swept key; timings and the summary in tabs of their own."""
    import rerun.blueprint as rrb

    bound_of = dict(bounds)
    shown = [m for m in metrics if m not in bound_of.values()]

    def plot(m):
        contents = [f"+ /metrics/{m}/**"] + ([f"+ /metrics/{bound_of[m]}/**"] if m in bound_of else [])
        name = f"{m} and {bound_of[m]}" if m in bound_of else m
        return rrb.TimeSeriesView(origin="/metrics", name=f"{name} vs {key}", contents=contents,
                                  plot_legend=rrb.PlotLegend(visible=m in bound_of, corner=rrb.Corner2D.RightTop))

    groups = {"against bounds": [m for m in shown if m in bound_of],
              "errors": [m for m in shown if m not in bound_of and "err" in m and not m.endswith("_s")],
              "other metrics": [m for m in shown if "err" not in m and not m.endswith("_s")],
              "timings": [m for m in shown if m.endswith("_s")]}
    tabs = [rrb.Grid(*[plot(m) for m in ms], name=name) for name, ms in groups.items() if ms]
    if not integer:
        tabs.append(rrb.TimeSeriesView(origin="/sweep", name=f"{key} per grid index", contents=["+ /sweep/**"]))
    tabs.append(rrb.TextDocumentView(origin="/summary", name="summary"))
    return rrb.Blueprint(rrb.Tabs(*tabs, active_tab=0), rrb.TimePanel(timeline=timeline, state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"), rrb.BlueprintPanel(state="collapsed"),
                         auto_layout=False, auto_views=False)
