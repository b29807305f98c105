"""Does the navigation follow its driver? Three looks the split benchmark does not give (docs/personal.md), each
fixed before any learner ran on its seeds, and the later looks at the changed learner (``preregistered/follow.yaml``,
``later_looks.yaml``). Judging takes seconds; the studies take about 3.5 min per seed (the sweep), 7-9 min (the
repeated drives) and 5.5 min (the headroom benchmark) on 2 cores.

* **the sweep's leads**: in the ``personal_sweep`` preset (the average driver, reaction time shifted), a learner's
  mean "turn" lead must rise with the driver's reaction time in each town and seed (Spearman over the sweep's
  points), cost the quickest driver at most 1.03 × explore and close 60 % of the slowest one's gap;
* **the personalization curve**: the ``repeat`` preset's drivers (two slow, two quick, fresh) each drive five
  rounds; the belief persists across them, so round *k* of a driver is its belief after *k* drives;
* **the headroom benchmark on fresh seeds**: the ``personal`` preset's cells, the belief learner against
  ``timing`` (the population baseline).

Example:
    >>> spearman([1, 2, 3, 4], [10, 20, 15, 40])
    0.8
"""

from __future__ import annotations

from typing import Any

import matplotlib
import numpy as np

from pernav.study.benchmarks import (
    LATE_EXCESS,
    REPEAT_DRIVERS,
    REPEAT_DRIVES,
    REPEAT_POPULATION_SEED,
    SWEEP_SHIFTS,
    classify,
    episodes,
    personal_schedule,
    repeat_schedule,
    sweep_schedule,
)
from pernav.study.config import BELIEF_DEFAULTS
from pernav.study.schedule import Entry
from pernav.study.stats import bootstrap_ci, gap_closed, paired_difference, paired_ratio
from pernav.world.drivers import resolve
from recipes.benchmarks.headroom import SPLIT_TARGETS, TARGETS, judge, plot_band
from recipes.benchmarks.registered import registration

__all__ = ["HEADROOM_FRESH_SEEDS", "HEADROOM_FRESH_TARGETS", "REPEAT_SEEDS", "REPEAT_TARGETS", "SWEEP_SEEDS",
           "SWEEP_TARGETS", "judge_headroom_fresh", "judge_repeat", "judge_sweep", "plot_personalization",
           "plot_sweep_leads", "preregistration", "repeat_second_look", "second_look", "spearman", "third_look",
           "third_version_looks"]

_FOLLOW, _LATER = registration("follow"), registration("later_looks")
#: the sweep's study seeds for this look (fresh: never run before this pre-registration)
SWEEP_SEEDS = tuple(_FOLLOW["sweep"]["seeds"])
SWEEP_TARGETS: dict[str, Any] = _FOLLOW["sweep"]["targets"]
REPEAT_SEEDS = tuple(_FOLLOW["repeat"]["seeds"])
REPEAT_TARGETS: dict[str, Any] = _FOLLOW["repeat"]["targets"]
#: the headroom benchmark's fresh seeds for the belief learner (never run before this pre-registration)
HEADROOM_FRESH_SEEDS = tuple(_FOLLOW["headroom"]["seeds"])
HEADROOM_FRESH_TARGETS: dict[str, Any] = {**_FOLLOW["headroom"]["targets"],
                                          "standing": {**_FOLLOW["headroom"]["standing"], "targets": TARGETS}}
#: the later looks (one each, fixed before it ran; ``later_looks.yaml`` says why each ran)
SECOND_LOOK_CHANGES: dict[str, Any] = _LATER["second"]["changes"]
SECOND_LOOK_SWEEP_SEEDS = tuple(_LATER["second"]["sweep_seeds"])
SECOND_LOOK_SPLIT_SEEDS = tuple(_LATER["second"]["split_seeds"])
THIRD_LOOK_CHANGES: dict[str, Any] = _LATER["third"]["changes"]
THIRD_LOOK_SPLIT_SEEDS = tuple(_LATER["third"]["split_seeds"])
REPEAT_SECOND_LOOK_SEEDS = tuple(_LATER["repeat_second"]["seeds"])
THIRD_VERSION_SWEEP_SEEDS = tuple(_LATER["third_version"]["sweep_seeds"])
THIRD_VERSION_HEADROOM_SEEDS = tuple(_LATER["third_version"]["headroom_seeds"])


def preregistration() -> dict[str, Any]:
    """The three looks as fixed before any learner ran on their seeds (JSON-ready)."""
    towns = ["Town1", "Town3"]
    return {"late_excess": LATE_EXCESS, "learner": "belief", "one_look": True,
            "sweep": {"preset": "personal_sweep", "seeds": list(SWEEP_SEEDS), "shifts": list(SWEEP_SHIFTS),
                      "targets": SWEEP_TARGETS, "cells": classify(sweep_schedule(), towns)},
            "repeat": {"preset": "repeat", "population_seed": REPEAT_POPULATION_SEED, "drivers_per_half": REPEAT_DRIVERS,
                       "drives": REPEAT_DRIVES, "seeds": list(REPEAT_SEEDS), "targets": REPEAT_TARGETS,
                       "cells": classify(repeat_schedule(), towns)},
            "headroom": {"preset": "personal", "seeds": list(HEADROOM_FRESH_SEEDS), "targets": HEADROOM_FRESH_TARGETS,
                         "cells": classify(personal_schedule(), towns)}}


def _look(options: dict[str, Any] | None = None, **parts: Any) -> dict[str, Any]:
    """A later look's registration (JSON-ready): the belief learner with ``options`` (default: as committed), read
    once, and ``parts`` (the look's number, why it ran, each benchmark's preset, seeds and targets)."""
    return {"learner": "belief", "options": dict(BELIEF_DEFAULTS if options is None else options), "one_look": True,
            **parts}


def second_look() -> dict[str, Any]:
    """The second look at the changed learner, as fixed before it ran (JSON-ready): the sweep and the split benchmark
    on fresh seeds, the same targets as their first looks, with the learner's options as committed."""
    options = {k: v for k, v in BELIEF_DEFAULTS.items() if k not in THIRD_LOOK_CHANGES}  # as they were then
    return _look(options, changed=SECOND_LOOK_CHANGES, look=2,
                 sweep={"preset": "personal_sweep", "seeds": list(SECOND_LOOK_SWEEP_SEEDS), "targets": SWEEP_TARGETS},
                 split={"preset": "split", "seeds": list(SECOND_LOOK_SPLIT_SEEDS), "targets": SPLIT_TARGETS})


def third_look() -> dict[str, Any]:
    """The split benchmark's third look, as fixed before it ran (JSON-ready): fresh seeds, the same targets as its
    first two looks, the learner's options as committed. A look repeated because the one before missed a target."""
    return _look(changed=THIRD_LOOK_CHANGES, look=3,
                 why="the second look missed the quick half's 'turn' lead (+0.35 s against at most 0.3)",
                 split={"preset": "split", "seeds": list(THIRD_LOOK_SPLIT_SEEDS), "targets": SPLIT_TARGETS})


def repeat_second_look() -> dict[str, Any]:
    """The repeated drives' second look, as fixed before it ran (JSON-ready): the same drivers and targets as the
    first look (:func:`preregistration`), fresh seeds, the learner's options as committed."""
    return _look(look=2, why="the first look ran the first version (reaction time only); the options have changed since",
                 repeat={"preset": "repeat", "population_seed": REPEAT_POPULATION_SEED,
                         "drivers_per_half": REPEAT_DRIVERS, "drives": REPEAT_DRIVES,
                         "seeds": list(REPEAT_SECOND_LOOK_SEEDS), "targets": REPEAT_TARGETS})


def third_version_looks() -> dict[str, Any]:
    """The third version's sweep and headroom looks, as fixed before they ran (JSON-ready): fresh seeds, the same
    targets and methods as their earlier looks, the learner's options as committed."""
    methods = ["explore", "timing", "belief", "oracle"]
    return _look(why="neither the sweep nor the headroom benchmark had run the third version (``slower``)",
                 sweep={"preset": "personal_sweep", "methods": methods, "seeds": list(THIRD_VERSION_SWEEP_SEEDS),
                        "look": 3, "targets": SWEEP_TARGETS},
                 headroom={"preset": "personal", "methods": methods, "seeds": list(THIRD_VERSION_HEADROOM_SEEDS),
                           "look": 2, "targets": HEADROOM_FRESH_TARGETS})


def spearman(x: list[float], y: list[float]) -> float:
    """Spearman's rank correlation (average ranks for ties); NaN when either side is constant.

    >>> spearman([1, 2, 3, 4], [10, 20, 15, 40])
    0.8
    """
    def ranks(v: list[float]) -> np.ndarray:
        a = np.asarray(v, dtype=float)
        order = a.argsort(kind="stable")
        r = np.empty(len(a))
        r[order] = np.arange(len(a), dtype=float)
        for value in np.unique(a):  # ties share their mean rank
            r[a == value] = r[a == value].mean()
        return r

    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return round(float(np.corrcoef(rx, ry)[0, 1]), 6)


def _reaction(entry: Entry) -> float:
    """The driver's reaction time in its context (what the belief reads: fog adds to it)."""
    return round(resolve(entry.profile(), entry.context()).reaction_time, 4)


def _leads(pairs: dict[tuple, dict[str, dict[str, Any]]], method: str, town: str, label: str,
           seed: int | None = None) -> list[float]:
    return [p[method]["turn_lead"] for k, p in pairs.items() if k[1] == town and k[2] == label
            and (seed is None or k[0] == seed) and method in p and p[method].get("turn_lead") is not None]


def _paired(pairs: dict[tuple, dict[str, dict[str, Any]]], labels: set[str], methods: tuple[str, ...],
            field: str = "tracking_cost", town: str | None = None) -> dict[str, np.ndarray]:
    keys = sorted(k for k, p in pairs.items() if k[2] in labels and set(methods) <= set(p)
                  and (town is None or k[1] == town) and all(p[m].get(field) is not None for m in methods))
    return {m: np.array([pairs[k][m][field] for k in keys], dtype=float) for m in methods}


def judge_sweep(results: list[dict[str, Any]], learner: str = "belief",
                methods: tuple[str, ...] = ("explore", "timing", "belief", "oracle")) -> dict[str, Any]:
    """The sweep look's figures (:data:`SWEEP_TARGETS`): every method's Spearman of mean "turn" lead with reaction
    time per town and seed, and the learner's cost at the quick end and gap closed at the slow end."""
    pairs = episodes(results)
    online = [e for e in sweep_schedule() if e.phase == "online"]
    reaction = {e.label: _reaction(e) for e in online}
    towns, seeds = sorted({k[1] for k in pairs}), sorted({k[0] for k in pairs})
    out: dict[str, Any] = {"learner": learner, "seeds": seeds, "reaction_times": list(reaction.values()),
                           "spearman": {}, "leads": {}}
    for method in methods:
        for town in towns:
            per_seed = {}
            for seed in seeds:
                points = [(reaction[label], _leads(pairs, method, town, label, seed)) for label in reaction]
                points = [(r, float(np.mean(v))) for r, v in points if v]
                if len(points) >= 3:
                    per_seed[str(seed)] = spearman(*map(list, zip(*points, strict=True)))
            if per_seed:
                out["spearman"].setdefault(method, {})[town] = per_seed
            leads = {label: _leads(pairs, method, town, label) for label in reaction}
            if any(leads.values()):
                out["leads"].setdefault(method, {})[town] = {
                    str(reaction[label]): round(float(np.mean(v)), 4) if v else None for label, v in leads.items()}
    quick, slow = {online[0].label}, {online[-1].label}
    for town in [None, *towns]:
        name = town or "pooled"
        q = _paired(pairs, quick, ("explore", learner), town=town)
        s = _paired(pairs, slow, ("explore", learner, "oracle"), town=town)
        row: dict[str, Any] = {}
        if len(q["explore"]):
            row["quick_end_cost_ratio"] = paired_ratio(q[learner], q["explore"])
        if len(s["explore"]):
            row["slow_end_gap_closed"] = gap_closed(s["explore"], s[learner], s["oracle"])
            row["slow_end"] = {m: float(s[m].mean()) for m in s}
        out[name] = row
    rhos = [r for town in out["spearman"].get(learner, {}).values() for r in town.values()]
    out["spearman_min"] = min(rhos) if rhos else None
    return out


def sweep_lines(judged: dict[str, Any]) -> list[str]:
    """:func:`judge_sweep`'s seeds, Spearman and mean "turn" leads per method and town, as printed lines."""
    lines = [f"seeds {judged['seeds']}; reaction times {judged['reaction_times']}"]
    for method, towns in judged["spearman"].items():
        lines += [f"spearman {method:12s} {town}: {rhos}" for town, rhos in towns.items()]
    for method, towns in judged["leads"].items():
        lines += [f"mean turn lead {method:12s} {town}: {leads}" for town, leads in towns.items()]
    return lines


def judge_repeat(results: list[dict[str, Any]], learner: str = "belief") -> dict[str, Any]:
    """The personalization curve (:data:`REPEAT_TARGETS`): per drive *k* of the same driver, the slow drivers' gap
    closed, the quick drivers' cost over explore's and "turn" lead minus explore's, and the belief's interval."""
    pairs = episodes(results)
    cells = classify(repeat_schedule(), ["Town1", "Town3"])
    late = {c["round"]: c["late"] for c in cells}  # a driver's class is its own, the same in both towns
    truth = {e.label: _reaction(e) for e in repeat_schedule() if e.phase == "online"}
    out: dict[str, Any] = {"learner": learner, "seeds": sorted({k[0] for k in pairs}), "drives": {}}
    for k in range(1, REPEAT_DRIVES + 1):
        labels = {label for label in late if label.endswith(f" drive {k}")}
        slow = _paired(pairs, {x for x in labels if late[x]}, ("explore", learner, "oracle"))
        quick = _paired(pairs, {x for x in labels if not late[x]}, ("explore", learner))
        lead = _paired(pairs, {x for x in labels if not late[x]}, ("explore", learner), "turn_lead")
        row: dict[str, Any] = {}
        if len(slow["explore"]):
            row["slow_gap_closed"] = gap_closed(slow["explore"], slow[learner], slow["oracle"])
            row["slow"] = {m: float(v.mean()) for m, v in slow.items()}
            row["slow_saved"] = {m: paired_difference(slow["explore"], slow[m]) for m in (learner, "oracle")}
        if len(quick["explore"]):
            row["quick_cost_ratio"] = paired_ratio(quick[learner], quick["explore"])
        if len(lead["explore"]):
            row["quick_turn_lead"] = paired_difference(lead[learner], lead["explore"])
        widths, errors = [], []
        for result in results:
            for diag in result.get("diagnostics", {}).values():
                for label, b in diag.get(learner, {}).get("beliefs", {}).items():
                    if label in labels:
                        widths.append(b["interval"][1] - b["interval"][0])
                        errors.append(abs(np.log(b["reaction_time"] / truth[label])))
        if widths:
            row["interval_width"] = round(float(np.mean(widths)), 4)
            row["abs_log_error"] = round(float(np.mean(errors)), 4)
        out["drives"][str(k)] = row
    return out


def judge_headroom_fresh(results: list[dict[str, Any]], learner: str = "belief",
                         baseline: str = "timing") -> dict[str, Any]:
    """The headroom look on fresh seeds (:data:`HEADROOM_FRESH_TARGETS`): :func:`recipes.benchmarks.headroom.judge` of
    the learner and of ``baseline`` on the same episodes, and the learner's late-cell cost above the baseline's as a
    share of the explore-to-oracle gap, with a paired bootstrap CI."""
    cells = classify(personal_schedule(), ["Town1", "Town3"])
    late = {(c["town"], c["round"]): c["late"] for c in cells}
    out = {"learner": judge(results, learner, cells), "baseline": judge(results, baseline, cells)}
    pairs = episodes(results)
    keys = sorted(k for k, p in pairs.items() if late.get((k[1], k[2])) and
                  {"explore", "oracle", learner, baseline} <= set(p))
    if keys:
        e, o, m, b = (np.array([pairs[k][x]["tracking_cost"] for k in keys], dtype=float)
                      for x in ("explore", "oracle", learner, baseline))

        def share(idx: np.ndarray) -> np.ndarray:
            gap = e[idx].mean(-1) - o[idx].mean(-1)
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(gap > 0, (m[idx].mean(-1) - b[idx].mean(-1)) / gap, np.nan)

        boot = share(np.random.default_rng(0).integers(0, len(keys), size=(4000, len(keys))))
        boot = boot[~np.isnan(boot)]
        out["late_minus_baseline"] = {"mean": float(share(np.arange(len(keys)))), "n": len(keys),
                                      "low": float(np.quantile(boot, 0.025)), "high": float(np.quantile(boot, 0.975))}
    return out


def _axes(n: int, width: float = 5.5):
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: after the headless backend is chosen

    fig, axes = plt.subplots(1, n, figsize=(width * n, 4), squeeze=False)
    return plt, fig, axes[0]


def plot_sweep_leads(results: list[dict[str, Any]], path: str,
                     methods: tuple[str, ...] = ("explore", "timing", "belief", "oracle")) -> dict[str, Any]:
    """The sweep's "turn" lead per method against the driver's reaction time (mean over routes and seeds with its
    95 % bootstrap CI), one panel per town; returns the plotted points."""
    pairs = episodes(results)
    towns = sorted({k[1] for k in pairs})
    online = [e for e in sweep_schedule() if e.phase == "online"]
    plt, fig, axes = _axes(len(towns))
    data: dict[str, Any] = {}
    for ax, town in zip(axes, towns, strict=True):
        data[town] = {}
        for method in methods:
            points = [(_reaction(e), *bootstrap_ci(v)) for e in online
                      if (v := _leads(pairs, method, town, e.label))]
            if not points:
                continue
            data[town][method] = points
            plot_band(ax, points, method)
        ax.set_title(town)
        ax.set_xlabel("the driver's reaction time (s)")
        ax.set_ylabel("'turn' prompt's lead (s: distance to the junction / speed)")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return data


def plot_personalization(judged: dict[str, Any], path: str) -> None:
    """The personalization curve from :func:`judge_repeat`, after each drive of the same driver (95 % CIs): what the
    learner and the oracle save the slow drivers per route against explore, the quick drivers' cost over explore's,
    and the width of the belief's 90 % interval."""
    plt, fig, (left, middle, right) = _axes(3, 4.6)
    rows = {int(k): v for k, v in judged["drives"].items()}
    x = sorted(rows)

    def bars(ax: Any, points: list[dict[str, float]], label: str, offset: float = 0.0) -> None:
        m = [p["mean"] for p in points]
        err = [[p["mean"] - p["low"] for p in points], [p["high"] - p["mean"] for p in points]]
        ax.errorbar([k + offset for k in x], m, yerr=err, marker="o", capsize=3, label=label)

    for name, offset in ((judged["learner"], -0.06), ("oracle", 0.06)):
        bars(left, [rows[k]["slow_saved"][name] for k in x], name, offset)
    left.axhline(0, color="0.6", lw=0.8, ls="--")
    left.set_ylabel("slow drivers: cost saved vs explore, per route")
    left.legend()
    bars(middle, [rows[k]["quick_cost_ratio"] for k in x], judged["learner"])
    middle.axhline(1.0, color="0.6", lw=0.8, ls="--")
    middle.set_ylabel("quick drivers: cost / explore's")
    right.plot(x, [rows[k]["interval_width"] for k in x], marker="o")
    right.set_ylabel("the belief's 90 % interval of the reaction time (s)")
    right.set_ylim(bottom=0)
    for ax in (left, middle, right):
        ax.set_xlabel("drives of the same driver")
        ax.set_xticks(x)
    fig.suptitle(f"{judged['learner']}: the personalization curve (seeds {', '.join(map(str, judged['seeds']))})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
