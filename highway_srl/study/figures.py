"""The study's figures, each as PNG and SVG with its data as CSV and Markdown beside it.

  deployment_pareto      Group 1: average speed (x) against collision-free rate C_r (y), one colour per
                         method, one marker per traffic level (the paper's deployment comparison figure)
  training_pareto        T_c (y) against rise time (x, reversed so that up-right is better), one colour per
                         method, one marker per scene (the paper's training comparison figure)
  training_curves_SCENE  return and cumulative training collisions against env steps, mean and ±1 sd
                         band over seeds, one colour per method
"""

from __future__ import annotations

import math
from pathlib import Path

from highway_srl.constants import TRAFFIC_LEVELS
from highway_srl.study import tables as T
from highway_srl.study.results import Results
from highway_srl.study.table import Table
from highway_srl.study.jobs import METHOD_LABELS, OURS, SCENES

LEVEL_MARKERS = dict(zip(TRAFFIC_LEVELS, ("o", "s", "^", "D", "v", "P")))
SCENE_MARKERS = dict(zip(SCENES, ("o", "s", "^", "D", "v", "P", "X", "*")))


def method_colours() -> dict[str, str]:
    """One fixed colour per method label, the same in every figure."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {label: matplotlib.colors.to_hex(cmap(i)) for i, label in enumerate(METHOD_LABELS.values())}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams["svg.hashsalt"] = "highway-srl"  # deterministic SVG ids
    return plt


def _save(fig, folder: Path, name: str) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    png, svg = folder / f"{name}.png", folder / f"{name}.svg"
    fig.savefig(png, dpi=120, bbox_inches="tight", metadata={"Software": None})
    fig.savefig(svg, bbox_inches="tight", metadata={"Date": None})
    return [png, svg]


def _emphasis(method_key: str) -> dict:
    """MoE-RM-SRL drawn larger and on top, so that baselines at the same point do not hide it."""
    return {"s": 80, "zorder": 4} if method_key == OURS else {"s": 46, "zorder": 3}


def _ok(v) -> bool:
    return v is not None and not (isinstance(v, float) and math.isnan(v))


def cap_rate_axis(ax, top: float) -> None:
    """A rate's axis ends at 100 % (`top`), not at matplotlib's margin above it; points on it stay whole."""
    low, high = ax.get_ylim()
    if high > top:
        ax.set_ylim(max(low, 0.0), top)
    for artist in ax.collections:
        artist.set_clip_on(False)


def _scatter(ax, table: Table, x: str, y: str, y_scale: float, marker_key: str, markers: dict,
             colours: dict) -> tuple[set, set]:
    """One point per row with both values: (row[x], y_scale * row[y]), coloured by method, marked by
    row[marker_key]. Returns the method labels and the marker keys drawn."""
    methods, keys = set(), set()
    for row in table.rows:
        if not (_ok(row[x]) and _ok(row[y])):
            continue
        ax.scatter(row[x], y_scale * row[y], color=colours.get(row["method"], "grey"),
                   marker=markers.get(row[marker_key], "o"), edgecolor="black", linewidth=0.4, alpha=0.85,
                   **_emphasis(row["method_key"]))
        methods.add(row["method"])
        keys.add(row[marker_key])
    return methods, keys


def _finish(plt, fig, ax, top: float, title: str, plotted: bool, folder: Path, name: str) -> list[Path]:
    """A Pareto figure's rate axis capped at `top`, title and grid (a note when nothing was plotted);
    saved as NAME.png / NAME.svg in folder and closed."""
    cap_rate_axis(ax, top)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if not plotted:
        ax.text(0.5, 0.5, "no finished runs yet", transform=ax.transAxes, ha="center")
    fig.tight_layout(rect=(0, 0, 0.8, 1))  # the right fifth holds the legends
    paths = _save(fig, folder, name)
    plt.close(fig)
    return paths


def deployment_pareto(results: Results, folder: Path) -> tuple[list[Path], Table]:
    plt = _pyplot()
    table = T.group1_deployment(results)
    table.name, table.title = "deployment_pareto", "Deployment Pareto figure data: speed against C_r, levels A-F"
    colours = method_colours()
    fig, ax = plt.subplots(figsize=(8.4, 4.8))
    plotted_methods, plotted_levels = _scatter(ax, table, "avg_speed", "C_r", 100.0, "level", LEVEL_MARKERS, colours)
    _legends(ax, plt, colours, plotted_methods,
             {lv: LEVEL_MARKERS[lv] for lv in TRAFFIC_LEVELS if lv in plotted_levels}, "level")
    ax.set_xlabel("average speed (m/s)")
    ax.set_ylabel("collision-free rate C_r (%)")
    paths = _finish(plt, fig, ax, 100.0, "Deployment on two-lane, trained at level C (upper right is better)",
                    bool(plotted_methods), folder, "deployment_pareto")
    return paths + table.write(folder), table


def training_pareto(results: Results, folder: Path) -> tuple[list[Path], Table]:
    plt = _pyplot()
    table = T.training(results)
    colours = method_colours()
    fig, ax = plt.subplots(figsize=(8.4, 4.8))
    plotted_methods, plotted_scenes = _scatter(ax, table, "rise_time", "T_c", 1.0, "scene_key", SCENE_MARKERS, colours)
    _legends(ax, plt, colours, plotted_methods,
             {SCENES[s].label: SCENE_MARKERS[s] for s in SCENES if s in plotted_scenes}, "scene")
    ax.invert_xaxis()
    ax.set_xlabel("rise time of the episode return (env steps; reversed: faster to the right)")
    ax.set_ylabel("training collision-free rate T_c")
    paths = _finish(plt, fig, ax, 1.0, "Training safety against learning speed (upper right is better)",
                    bool(plotted_methods), folder, "training_pareto")
    return paths + table.write(folder), table


def _legends(ax, plt, colours, methods, markers: dict[str, str], title: str) -> None:
    from matplotlib.lines import Line2D

    if not methods:
        return
    order = [lab for lab in METHOD_LABELS.values() if lab in methods]
    h1 = [Line2D([], [], color=colours[m], marker="o", linestyle="", markersize=7) for m in order]
    first = ax.legend(h1, order, title="method", loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8,
                      title_fontsize=8, frameon=False)
    ax.add_artist(first)
    h2 = [Line2D([], [], color="grey", marker=mk, linestyle="", markersize=7, markeredgecolor="black")
          for mk in markers.values()]
    ax.legend(h2, list(markers), title=title, loc="lower left", bbox_to_anchor=(1.02, 0.0), fontsize=8,
              title_fontsize=8, frameon=False)


def training_curves(results: Results, folder: Path) -> tuple[list[Path], Table]:
    plt = _pyplot()
    table, series = T.training_curves(results)
    colours = method_colours()
    paths = []
    for scene, by_method in series.items():
        fig, (ax_r, ax_c) = plt.subplots(1, 2, figsize=(10, 3.8))
        for label, rows in by_method.items():
            c = colours.get(label, "grey")
            pts = [(r["step"], r["return_mean"], r["return_sd"]) for r in rows if _ok(r["return_mean"])]
            few = len(pts) < 4
            if pts:
                xs, ys, sds = zip(*pts)
                ax_r.plot(xs, ys, color=c, label=label, marker="o" if few else None)
                if any(_ok(s) for s in sds):
                    lo = [y - (s or 0.0) for y, s in zip(ys, sds)]
                    hi = [y + (s or 0.0) for y, s in zip(ys, sds)]
                    ax_r.fill_between(xs, lo, hi, color=c, alpha=0.2, linewidth=0)
            xs = [r["step"] for r in rows]
            ys = [r["collisions_mean"] for r in rows]
            ax_c.plot(xs, ys, color=c, label=label)
            if any(_ok(r["collisions_sd"]) for r in rows):
                ax_c.fill_between(xs, [y - (r["collisions_sd"] or 0.0) for y, r in zip(ys, rows)],
                                  [y + (r["collisions_sd"] or 0.0) for y, r in zip(ys, rows)],
                                  color=c, alpha=0.2, linewidth=0)
        ax_r.set_xlabel("env steps per seed")
        ax_r.set_ylabel("training episode return")
        ax_c.set_xlabel("env steps per seed")
        ax_c.set_ylabel("cumulative training collisions")
        ax_r.grid(alpha=0.3)
        ax_c.grid(alpha=0.3)
        ax_r.legend(fontsize=7, loc="best")
        fig.suptitle(f"Training curves: {SCENES[scene].label} (mean and ±1 sd over seeds)")
        fig.tight_layout()
        paths += _save(fig, folder, f"training_curves_{scene}")
        plt.close(fig)
    return paths + table.write(folder), table


def all_figures(results: Results, folder: Path) -> tuple[list[Path], dict[str, Table]]:
    """Every figure (PNG, SVG) with its data (CSV, Markdown); the paths and the data tables by name."""
    paths, tables = [], {}
    for make in (deployment_pareto, training_pareto, training_curves):
        p, table = make(results, folder)
        paths += p
        tables[table.name] = table
    return paths, tables
