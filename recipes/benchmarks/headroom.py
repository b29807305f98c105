"""The headroom and split benchmarks' judging: a learner's pre-registered figures from the studies' results (seconds
on a laptop; the studies themselves take about 5.5 min per seed for the headroom benchmark and 4.2 min for the split
one on 2 cores). The cells, drivers and classes are the library's (:mod:`pernav.study.benchmarks`); the seeds and
targets are data, committed before any learner ran on them (``preregistered/headroom.yaml``, ``split.yaml``).

Example:
    >>> preregistration(["Town1"])["seeds"]
    [0, 1, 2, 3, 4, 5]
"""

from __future__ import annotations

from typing import Any

import matplotlib
import numpy as np

from pernav.env.policies import lateness
from pernav.study.benchmarks import (
    LATE_EXCESS,
    PERSONAL_POPULATION_SEED,
    SPLIT_DRIVERS,
    SPLIT_POPULATION_SEED,
    SWEEP_SHIFTS,
    classify,
    episodes,
    personal_schedule,
    split_schedule,
    sweep_schedule,
)
from pernav.study.stats import bootstrap_ci, gap_closed, paired_difference, paired_ratio
from pernav.world.drivers import resolve
from recipes.benchmarks.registered import registration

__all__ = ["SEEDS", "SPLIT_SEEDS", "SPLIT_TARGETS", "TARGETS", "judge", "judge_markdown", "judge_split", "plot_band",
           "plot_sweep", "preregistration", "split_preregistration"]

_HEADROOM, _SPLIT = registration("headroom"), registration("split")
#: the study seeds that judge a learner on the headroom benchmark
SEEDS = tuple(_HEADROOM["seeds"])
#: what a learner must reach (fixed before any learner ran on the benchmark)
TARGETS: dict[str, Any] = _HEADROOM["targets"]
#: the study seeds of the split benchmark's first look (fresh: never run before its pre-registration)
SPLIT_SEEDS = tuple(_SPLIT["seeds"])
#: what the belief learner must reach on the split benchmark (fixed before any learner ran on it)
SPLIT_TARGETS: dict[str, Any] = _SPLIT["targets"]


def split_preregistration(towns: tuple[str, ...] = ("Town1", "Town3")) -> dict[str, Any]:
    """The split benchmark as fixed before any learner runs on it: its drivers, cells and classes, seeds, targets."""
    return {"towns": list(towns), "late_excess": LATE_EXCESS, "population_seed": SPLIT_POPULATION_SEED,
            "drivers_per_half": SPLIT_DRIVERS, "seeds": list(SPLIT_SEEDS), "targets": SPLIT_TARGETS,
            "cells": classify(split_schedule(), list(towns))}


def judge_split(results: list[dict[str, Any]], learner: str = "belief", baseline: str = "timing") -> dict[str, Any]:
    """The split benchmark's pre-registered figures (:data:`SPLIT_TARGETS`) of ``learner``: :func:`judge`'s on the
    split cells, and the quick half's "turn" lead against explore's and every cell against ``baseline``."""
    cells = classify(split_schedule(), ["Town1", "Town3"])
    out = judge(results, learner, cells)
    late = {(c["town"], c["round"]): c["late"] for c in cells}
    pairs = {k: v for k, v in episodes(results).items() if (k[1], k[2]) in late}

    def keys(want: bool | None, methods: tuple[str, ...]) -> list[tuple]:
        return sorted(k for k, v in pairs.items() if set(methods) <= set(v)
                      and (want is None or late[(k[1], k[2])] == want))

    def values(ks: list[tuple], method: str, field: str = "tracking_cost") -> np.ndarray:
        return np.array([pairs[k][method][field] for k in ks], dtype=float)

    quick = [k for k in keys(False, ("explore", learner))
             if pairs[k]["explore"].get("turn_lead") is not None and pairs[k][learner].get("turn_lead") is not None]
    if quick:
        # the learner's lead minus explore's (> 0: its "turn" prompts come earlier)
        out["quick_turn_lead"] = paired_difference(values(quick, learner, "turn_lead"),
                                                   values(quick, "explore", "turn_lead"))
    for name, want in (("all", None), ("quick", False), ("slow", True)):
        ks = keys(want, (learner, baseline))
        if ks:
            out[f"{name}_against_{baseline}"] = {"ratio": paired_ratio(values(ks, learner), values(ks, baseline)),
                                                 "difference": paired_difference(values(ks, baseline),
                                                                                 values(ks, learner))}
    return out


def preregistration(towns: list[str]) -> dict[str, Any]:
    """The benchmark as fixed before any learner runs: cells and classes, seeds, targets (JSON-ready)."""
    return {"towns": list(towns), "late_excess": LATE_EXCESS, "population_seed": PERSONAL_POPULATION_SEED,
            "seeds": list(SEEDS), "targets": TARGETS, "cells": classify(personal_schedule(), towns)}


def judge(results: list[dict[str, Any]], learner: str = "timing", cells: list[dict[str, Any]] | None = None
          ) -> dict[str, Any]:
    """The pre-registered figures of ``learner`` (and of explore and the oracle) on the benchmark's episodes:
    the gap closed on the late cells (pooled and per town), the on-time cost ratio, collisions over all cells and
    the comparison with ``adapt`` and ``sysid`` where they drove the same episodes (95 % paired bootstrap CIs)."""
    late = {(c["town"], c["round"]): c["late"] for c in (cells or classify(personal_schedule(), ["Town1", "Town3"]))}
    pairs = episodes(results)

    def values(keys: list[tuple], method: str, field: str = "tracking_cost") -> np.ndarray:
        return np.array([pairs[k][method][field] for k in keys], dtype=float)

    def select(want: bool | None, methods: tuple[str, ...], town: str | None = None) -> list[tuple]:
        return sorted(k for k, v in pairs.items() if set(methods) <= set(v) and (k[1], k[2]) in late
                      and (want is None or late[(k[1], k[2])] == want) and (town is None or k[1] == town))

    ran = select(None, ("explore", learner)) or select(None, ("explore",))
    out: dict[str, Any] = {"learner": learner, "seeds": sorted({k[0] for k in ran})}
    base = ("explore", "oracle")
    for name, want in (("late", True), ("on_time", False)):
        keys = select(want, (*base, learner)) or select(want, base)  # the learner's episodes where it ran
        if not keys:
            continue
        row: dict[str, Any] = {"episodes": len(keys), "explore": float(values(keys, "explore").mean()),
                               "oracle": float(values(keys, "oracle").mean()),
                               "oracle_gain": paired_difference(values(keys, "explore"), values(keys, "oracle"))}
        with_learner = select(want, (*base, learner))
        if with_learner:
            e, m, o = (values(with_learner, x) for x in ("explore", learner, "oracle"))
            row.update({"learner": float(m.mean()), "learner_episodes": len(with_learner),
                        "gap_closed": gap_closed(e, m, o), "cost_ratio": paired_ratio(m, e),
                        "per_town": {}})
            for town in sorted({k[1] for k in with_learner}):
                tk = select(want, (*base, learner), town)
                te, tm, to = (values(tk, x) for x in ("explore", learner, "oracle"))
                row["per_town"][town] = {"explore": float(te.mean()), "oracle": float(to.mean()),
                                         "learner": float(tm.mean()), "oracle_gain": paired_difference(te, to),
                                         "gap_closed": gap_closed(te, tm, to)}
            for other in ("adapt", "sysid"):
                ok = select(want, (learner, other))
                if ok:
                    row[f"minus_{other}"] = paired_difference(values(ok, learner), values(ok, other))
                    row[f"minus_{other}"]["seeds"] = sorted({k[0] for k in ok})
        out[name] = row
    every = select(None, ("explore", learner))
    if every:
        out["collisions"] = {"explore": float(values(every, "explore", "collisions").sum()),
                             "learner": float(values(every, learner, "collisions").sum()),
                             "learner_minus_explore": paired_difference(values(every, learner, "collisions"),
                                                                        values(every, "explore", "collisions"))}
    return out


def _ci(x: dict[str, float], scale: float = 1.0, fmt: str = "{:+.0f}", unit: str = "") -> str:
    """``mean [low, high]`` of a CI dict, scaled and formatted."""
    m, lo, hi = (fmt.format(x[k] * scale) for k in ("mean", "low", "high"))
    return f"{m}{unit} [{lo}, {hi}]"


def judge_markdown(j: dict[str, Any]) -> str:
    """The judged figures as a Markdown table (what docs/personal.md shows)."""
    learner = j["learner"]
    lines = [f"Seeds {', '.join(map(str, j['seeds']))}; paired episodes, 95 % bootstrap CIs.", "",
             f"| cells | episodes | explore | oracle | {learner} | oracle − explore | gap closed by {learner} | "
             f"{learner} / explore |", "|---|---|---|---|---|---|---|---|"]
    for name in ("late", "on_time"):
        r = j.get(name)
        if not r:
            continue
        gain = {k: -v for k, v in r["oracle_gain"].items() if k != "n"}
        gain["low"], gain["high"] = gain["high"], gain["low"]
        closed = _ci(r["gap_closed"], 100, "{:.0f}", " %") if "gap_closed" in r else "–"
        ratio = _ci(r["cost_ratio"], 1, "{:.3f}") if "cost_ratio" in r else "–"
        lines.append(f"| {name.replace('_', ' ')} | {r['episodes']} | {r['explore']:.0f} | {r['oracle']:.0f} | "
                     f"{r.get('learner', float('nan')):.0f} | {_ci(gain)} | {closed} | {ratio} |")
        for town, t in r.get("per_town", {}).items():
            g = {"mean": -t["oracle_gain"]["mean"], "low": -t["oracle_gain"]["high"], "high": -t["oracle_gain"]["low"]}
            lines.append(f"| {name.replace('_', ' ')}, {town} | | {t['explore']:.0f} | {t['oracle']:.0f} | "
                         f"{t['learner']:.0f} | {_ci(g)} | {_ci(t['gap_closed'], 100, '{:.0f}', ' %')} | |")
    lines.append("")
    late = j.get("late", {})
    for other in ("adapt", "sysid"):
        if f"minus_{other}" in late:
            d = late[f"minus_{other}"]
            lines.append(f"- Late cells, {learner} − {other} (seeds {', '.join(map(str, d['seeds']))}, {d['n']} "
                         f"episodes): {_ci(d)}")
    if "collisions" in j:
        c = j["collisions"]
        lines.append(f"- Collisions over all cells: explore {c['explore']:.0f}, {learner} {c['learner']:.0f}; "
                     f"{learner} − explore per episode {_ci(c['learner_minus_explore'], 1, '{:+.3f}')}")
    return "\n".join(lines) + "\n"


def plot_band(ax: Any, points: list[tuple[float, float, float, float]], label: str) -> None:
    """One method's ``(x, mean, low, high)`` points: a line with markers and its CI band."""
    x, m, lo, hi = (list(c) for c in zip(*points, strict=True))
    ax.plot(x, m, marker="o", label=label)
    ax.fill_between(x, lo, hi, alpha=0.15)


def plot_sweep(results: list[dict[str, Any]], path: str, methods: tuple[str, ...] = ("explore", "adapt", "timing",
                                                                                        "oracle")) -> dict[str, Any]:
    """The headroom sweep's figure: mean tracking cost (95 % CI over routes and seeds) per reaction-time shift,
    one panel per town; returns the plotted figures."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: after the headless backend is chosen

    pairs = episodes(results)
    towns = sorted({k[1] for k in pairs})
    online = [e for e in sweep_schedule() if e.phase == "online"]
    labels = [e.label for e in online]
    on_time_up_to = max(shift for shift, e in zip(SWEEP_SHIFTS, online, strict=True)
                        if lateness(resolve(e.profile(), e.context()))["excess"] < LATE_EXCESS)
    data: dict[str, Any] = {}
    fig, axes = plt.subplots(1, len(towns), figsize=(5.5 * len(towns), 4), squeeze=False)
    for ax, town in zip(axes[0], towns, strict=True):
        data[town] = {}
        for method in methods:
            points = []
            for shift, label in zip(SWEEP_SHIFTS, labels, strict=True):
                v = [p[method]["tracking_cost"] for k, p in pairs.items() if k[1] == town and k[2] == label
                     and method in p]
                if v:
                    points.append((shift, *bootstrap_ci(v)))
            if not points:
                continue
            data[town][method] = points
            plot_band(ax, points, method)
        ax.set_title(town)
        ax.set_xlabel("reaction time − the average driver's (s)")
        ax.set_ylabel("tracking cost per route")
        ax.axvspan(min(SWEEP_SHIFTS) - 0.05, on_time_up_to + 0.2, color="0.92", zorder=0,
                   label="on time (classified)")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return data
