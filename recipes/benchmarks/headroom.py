"""The headroom benchmark: drivers across the spectrum, each (town, round) cell classified *late* or *on time*
before any learner runs (docs/personal.md).

Explore's prompts are timed for the average driver with 0.8 s of slack; personal timing pays only for drivers
outside that slack. The ``personal`` preset's online rounds are named users and population-prior draws, at least
half of them outside it. A cell is *late* when explore's "turn" prompts reach the driver after its commit point
in at least :data:`LATE_EXCESS` more of the prompts than the oracle's, from the driver's resolved profile alone
(:func:`pernav.env.policies.lateness`: analytic, no simulation, no learner).

Example:
    >>> cells = classify(personal_schedule(), ["Town1"])
    >>> sum(c["late"] for c in cells) >= len(cells) / 2
    True
"""

from __future__ import annotations

from typing import Any

from pernav.env.policies import lateness
from pernav.study.schedule import Entry, paper_schedule
from pernav.world.drivers import Population, resolve

__all__ = ["LATE_EXCESS", "PERSONAL_POPULATION_SEED", "SEEDS", "SWEEP_SHIFTS", "TARGETS", "classify", "episodes",
           "judge", "judge_markdown", "judge_split", "offline_rounds", "personal_schedule", "plot_sweep", "preregistration",
           "split_drivers", "split_preregistration", "split_schedule", "sweep_schedule"]

#: a cell is late when explore is late for the commit in at least this share more of the prompts than the oracle
LATE_EXCESS = 0.05
#: the seed of the benchmark's population-prior drivers (fixed before any run; not the diagnostics panel's)
PERSONAL_POPULATION_SEED = 38
POPULATION_DRAWS = 8
#: the study seeds that judge a learner on the benchmark
SEEDS = (0, 1, 2, 3, 4, 5)
#: what a learner must reach (fixed before any learner ran on the benchmark)
TARGETS: dict[str, Any] = {
    "late_gap_closed": {"point": 0.60, "ci_low": 0.30,
                        "what": "share of explore's tracking cost above the oracle's that the learner removes, late "
                                "cells pooled over towns and seeds, paired with explore on the same episodes"},
    "late_gap_closed_per_town": {"point": 0.40, "what": "the same per town, where the oracle's own gain is clear "
                                                       "of zero (its 95 % CI above 0)"},
    "on_time_cost_ratio": {"point": 1.03, "ci_high": 1.08,
                           "what": "learner's tracking cost over explore's on the on-time cells"},
    "collisions": {"what": "learner's collisions minus explore's over all cells: the 95 % CI includes or lies "
                           "below zero"},
    "against_adapt_sysid": {"what": "learner's tracking cost minus adapt's and minus sysid's on the late cells: "
                                    "95 % CI below zero"},
    "stretch": {"late_gap_closed": 0.80, "what": "reported either way: above 80 %, or beyond the oracle"},
}
_NAMED = [  # (label, user, context): four outside explore's slack, four inside
    ("user3", "user3", {}),
    ("user2", "user2", {}),
    ("user5", "user5", {}),
    ("user1 truck fog", "user1", {"vehicle": "cybertruck", "visual": "foggy"}),
    ("user4", "user4", {}),
    ("user6", "user6", {}),
    ("user7 wheel", "user7", {"equipment": "wheel"}),
    ("user1 wheel", "user1", {"equipment": "wheel"}),
]


def personal_schedule() -> list[Entry]:
    """The ``personal`` preset's schedule: the default study's three offline rounds (user1), then eight named-user
    rounds and :data:`POPULATION_DRAWS` population-prior rounds (``Population(seed=PERSONAL_POPULATION_SEED)``)."""
    entries = offline_rounds()
    entries += [Entry(label, "online", user, **context) for label, user, context in _NAMED]
    pop = Population(seed=PERSONAL_POPULATION_SEED)
    for i in range(POPULATION_DRAWS):
        profile, context = pop.sample()
        entries.append(Entry(f"population {i}", "online", profile.to_dict(), **context.to_dict()))
    return entries


#: the headroom sweep: the average driver (average context) with its reaction time shifted by these seconds
SWEEP_SHIFTS = (-0.4, 0.0, 0.4, 0.8, 1.2)


def sweep_schedule() -> list[Entry]:
    """The ``personal_sweep`` preset's schedule: the default study's offline rounds, then one online round per
    reaction-time shift of the average driver (:data:`SWEEP_SHIFTS`; every other trait and the context average)."""
    from pernav.world.drivers import POPULATION_AVERAGE

    entries = offline_rounds()
    for shift in SWEEP_SHIFTS:
        profile = {**POPULATION_AVERAGE.to_dict(), "reaction_time": round(POPULATION_AVERAGE.reaction_time + shift, 2)}
        entries.append(Entry(f"reaction {shift:+.1f} s", "online", profile))
    return entries


#: the split benchmark's population-prior drivers (fixed before any run; used nowhere else)
SPLIT_POPULATION_SEED = 4848
SPLIT_DRIVERS = 5  # drivers of each half
#: the study seeds that judge a learner on the split benchmark (fresh: never run before its pre-registration)
SPLIT_SEEDS = tuple(range(100, 116))


def split_schedule() -> list[Entry]:
    """The ``split`` preset's schedule, where the population's prior is no guide: the default study's offline rounds,
    then :data:`SPLIT_DRIVERS` slow drivers (outside explore's slack: the cell is late, :func:`classify`) and as many
    quick ones (inside it), alternating, the first draws of each kind from
    ``Population(seed=SPLIT_POPULATION_SEED)``. Re-timing everybody says early prompts to the quick half; keeping
    explore leaves the slow half late; only a learner that tells them apart serves both.

    >>> [e.label for e in split_schedule()[3:6]]
    ['slow 0', 'quick 0', 'slow 1']
    """
    entries = offline_rounds()
    kinds = split_drivers(SPLIT_POPULATION_SEED, SPLIT_DRIVERS)
    for i in range(SPLIT_DRIVERS):
        for kind in ("slow", "quick"):
            profile, context = kinds[kind][i]
            entries.append(Entry(f"{kind} {i}", "online", profile.to_dict(), **context.to_dict()))
    return entries


def offline_rounds() -> list[Entry]:
    """The default study's three offline rounds (user1), which every benchmark schedule starts with."""
    by_label = {e.label: e for e in paper_schedule()}
    return [by_label[x] for x in ("Offline 0", "Offline 1", "Offline 2")]


def split_drivers(population_seed: int, n: int) -> dict[str, list[tuple[Any, Any]]]:
    """The first ``n`` slow (outside explore's slack: late, :func:`classify`) and ``n`` quick (inside it) drivers drawn
    from ``Population(seed=population_seed)``, as ``{"slow": [(profile, context), ...], "quick": [...]}``; drivers
    in neither class (late for the oracle too) are skipped.

    >>> [len(v) for v in split_drivers(SPLIT_POPULATION_SEED, 2).values()]
    [2, 2]
    """
    pop, kinds = Population(seed=population_seed), {"slow": [], "quick": []}
    while min(len(v) for v in kinds.values()) < n:
        profile, context = pop.sample()
        late = lateness(resolve(profile, context))
        kind = "slow" if late["excess"] >= LATE_EXCESS else "quick" if late["explore"] < LATE_EXCESS else None
        if kind is not None and len(kinds[kind]) < n:
            kinds[kind].append((profile, context))
    return kinds


#: what the belief learner must reach on the split benchmark (fixed before any learner ran on it; from the issue)
SPLIT_TARGETS: dict[str, Any] = {
    "slow_gap_closed": {"point": 0.60, "ci_low": 0.30,
                        "what": "slow half (late cells): share of explore's tracking cost above the oracle's that the "
                                "learner removes, pooled over towns and seeds, paired with explore"},
    "quick_cost_ratio": {"point": 1.01, "ci_high": 1.04,
                         "what": "quick half (on-time cells): learner's tracking cost over explore's"},
    "quick_turn_lead": {"point": 0.3, "what": "quick half: the learner's mean 'turn' lead minus explore's (s), paired "
                                              "per episode, at most this much earlier"},
    "all_against_timing": {"point": 1.02, "ci_high": 1.03,
                           "what": "all cells: learner's tracking cost over timing's (the population baseline); the "
                                   "quick half's difference to timing reported either way"},
    "collisions": {"what": "learner's collisions minus explore's over all cells: the 95 % CI includes or lies below "
                           "zero"},
}


def split_preregistration(towns: tuple[str, ...] = ("Town1", "Town3")) -> dict[str, Any]:
    """The split benchmark as fixed before any learner runs on it: its drivers, cells and classes, seeds, targets."""
    return {"towns": list(towns), "late_excess": LATE_EXCESS, "population_seed": SPLIT_POPULATION_SEED,
            "drivers_per_half": SPLIT_DRIVERS, "seeds": list(SPLIT_SEEDS), "targets": SPLIT_TARGETS,
            "cells": classify(split_schedule(), list(towns))}


def judge_split(results: list[dict[str, Any]], learner: str = "belief", baseline: str = "timing") -> dict[str, Any]:
    """The split benchmark's pre-registered figures (:data:`SPLIT_TARGETS`) of ``learner``: :func:`judge`'s on the
    split cells, and the quick half's "turn" lead against explore's and every cell against ``baseline``."""
    import numpy as np

    from pernav.study.stats import paired_difference, paired_ratio

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


def classify(entries: list[Entry], towns: list[str]) -> list[dict[str, Any]]:
    """Every online (town, round) cell with explore's and the oracle's late shares and its class, from the
    round's driver profile and context alone."""
    cells = []
    for town in towns:
        for e in entries:
            if e.phase != "online" or not e.runs_in(town) or e.drives:
                continue
            late = lateness(resolve(e.profile(), e.context()))
            cells.append({"town": town, "round": e.label, "explore_late": round(late["explore"], 4),
                          "oracle_late": round(late["oracle"], 4), "late": bool(late["excess"] >= LATE_EXCESS)})
    return cells


def preregistration(towns: list[str]) -> dict[str, Any]:
    """The benchmark as fixed before any learner runs: cells and classes, seeds, targets (JSON-ready)."""
    return {"towns": list(towns), "late_excess": LATE_EXCESS, "population_seed": PERSONAL_POPULATION_SEED,
            "seeds": list(SEEDS), "targets": TARGETS, "cells": classify(personal_schedule(), towns)}


def episodes(results: list[dict[str, Any]]) -> dict[tuple, dict[str, dict[str, Any]]]:
    """``{(seed, town, round, route): {method: episode}}`` from studies' ``results.json`` (several studies of one
    seed, e.g. each with other methods, drive the same episodes and merge)."""
    out: dict[tuple, dict[str, dict[str, Any]]] = {}
    for result in results:
        seed = result["config"]["seed"]
        for it in result["iterations"]:
            if it["phase"] != "online":
                continue
            for town, methods in it["towns"].items():
                for method, figures in methods.items():
                    for e in figures["episodes"]:
                        out.setdefault((seed, town, it["label"], e["route"]), {})[method] = e
    return out


def judge(results: list[dict[str, Any]], learner: str = "timing", cells: list[dict[str, Any]] | None = None
          ) -> dict[str, Any]:
    """The pre-registered figures of ``learner`` (and of explore and the oracle) on the benchmark's episodes:
    the gap closed on the late cells (pooled and per town), the on-time cost ratio, collisions over all cells and
    the comparison with ``adapt`` and ``sysid`` where they drove the same episodes (95 % paired bootstrap CIs)."""
    import numpy as np

    from pernav.study.stats import gap_closed, paired_difference, paired_ratio

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


def plot_sweep(results: list[dict[str, Any]], path: str, methods: tuple[str, ...] = ("explore", "adapt", "timing",
                                                                                        "oracle")) -> dict[str, Any]:
    """The headroom sweep's figure: mean tracking cost (95 % CI over routes and seeds) per reaction-time shift,
    one panel per town; returns the plotted figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pernav.study.stats import bootstrap_ci

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
            x, m, lo, hi = (list(c) for c in zip(*points, strict=True))
            ax.plot(x, m, marker="o", label=method)
            ax.fill_between(x, lo, hi, alpha=0.15)
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
