"""report.md and figures/ from results.json: running-average cost bars, collision table, regret curves."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

from pernav.study.config import METHODS

__all__ = ["collision_table", "running_mean", "wall_time", "write_report"]

COLORS = {"explore": "#7f7f7f", "sysid": "#1f77b4", "adapt": "#d62728", "adapt_speed": "#ff7f0e",
          "hindsight": "#2ca02c", "oracle": "#9467bd", "adapt_driver": "#17becf"}


def _online(results: dict[str, Any], town: str) -> list[dict[str, Any]]:
    # a round of recorded drives has no episodes (docs/study.md, "Recorded drives in a schedule")
    return [it for it in results["iterations"] if it["phase"] == "online" and it["towns"].get(town)]


def wall_time(results: dict[str, Any]) -> dict[str, Any]:
    """The wall-time entry of a results.json or a compact paper town (``wall_s`` of the whole run, ``workers``, per
    town the rounds' seconds and the phases' ``profile``); files written before its rename hold it as ``timing``
    (a name that now means the timing learner alone). Empty when absent.

    >>> wall_time({"timing": {"wall_s": 60.0}}), wall_time({"wall_time": {"wall_s": 61.0}}), wall_time({})
    ({'wall_s': 60.0}, {'wall_s': 61.0}, {})
    """
    return results.get("wall_time", results.get("timing")) or {}


def running_mean(values: list[float]) -> list[float]:
    """The average of the values up to each position (the paper's "average upon the current iteration")."""
    out, total = [], 0.0
    for i, v in enumerate(values, 1):
        total += v
        out.append(total / i)
    return out


def plot_costs(results: dict[str, Any], town: str, path: Path) -> None:
    """Paper Fig. 3: running average of the episodic cost up to each online round, one bar per method."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: after the headless backend is chosen

    rounds = _online(results, town)
    methods = [m for m in METHODS if all(m in it["towns"][town] for it in rounds)]
    fig, ax = plt.subplots(figsize=(max(6, 1.1 * len(rounds) + 2), 3.6))
    width = 0.8 / max(len(methods), 1)
    for j, m in enumerate(methods):
        values = running_mean([it["towns"][town][m]["tracking_cost"] for it in rounds])
        ax.bar([i + (j - (len(methods) - 1) / 2) * width for i in range(len(rounds))], values, width,
               label=m, color=COLORS.get(m))
    ax.set_xticks(range(len(rounds)), [it["label"].replace("Online ", "") for it in rounds])
    ax.set_xlabel("online round")
    ax.set_ylabel("avg. episodic cost so far")
    ax.set_title(f"{town}: running-average tracking cost")
    ax.legend(fontsize=7, ncol=len(methods), loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_regret(results: dict[str, Any], town: str, path: Path) -> None:
    """Empirical regret of adapt vs hindsight: per-round model-loss gap and its running average."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: after the headless backend is chosen

    reg = results["regret"].get(town)
    if not reg or not reg["labels"]:
        return
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    x = range(1, len(reg["labels"]) + 1)
    axes[0].plot(x, reg["loss_regret"], "o-", label="per round")
    axes[0].plot(x, reg["average_loss_regret"], "s--", label="average up to round")
    axes[0].set_title("model-loss regret (adapt - hindsight)")
    if reg["cost_regret"]:
        axes[1].plot(x[: len(reg["cost_regret"])], reg["cost_regret"], "o-", label="per round")
        axes[1].plot(x[: len(reg["cost_regret"])], reg["average_cost_regret"], "s--", label="average up to round")
    axes[1].set_title("episodic-cost regret (adapt - hindsight)")
    for ax in axes:
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel("online round")
        ax.legend(fontsize=7)
    fig.suptitle(town)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def collision_table(results: dict[str, Any]) -> str:
    """Markdown: per town, collisions per route set (mean (std) over online rounds) and mean cost."""
    summary = results["summary"]
    methods = [m for m in METHODS if any(m in s for s in summary.values())]
    lines = ["| town | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for town, s in summary.items():
        cells = [f"{s[m]['collisions_mean']:.2f} ({s[m]['collisions_std']:.2f})" if m in s else "–" for m in methods]
        lines.append(f"| {town} collisions | " + " | ".join(cells) + " |")
        cells = [f"{s[m]['tracking_cost_mean']:.0f}" if m in s else "–" for m in methods]
        lines.append(f"| {town} tracking cost | " + " | ".join(cells) + " |")
        cells = [f"{100 * s[m]['completion_mean']:.0f} %" if m in s else "–" for m in methods]
        lines.append(f"| {town} completion | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _headline(results: dict[str, Any]) -> list[str]:
    """The paper's targets, checked on these results (honest: states misses)."""
    out = []
    for town, s in results["summary"].items():
        if "explore" not in s:
            continue
        ex = s["explore"]
        for m in ("adapt", "adapt_speed"):
            if m in s and ex["collisions_mean"] > 0:
                red = 100 * (1 - s[m]["collisions_mean"] / ex["collisions_mean"])
                out.append(f"- {town}: {m} has {red:+.0f} % fewer collisions than explore "
                           f"({s[m]['collisions_mean']:.2f} vs {ex['collisions_mean']:.2f}; paper: "
                           f"{'50' if m == 'adapt' else '60'} %).")
            elif m in s:
                out.append(f"- {town}: explore had no collisions; {m} had {s[m]['collisions_mean']:.2f} per round.")
        rounds = _online(results, town)
        if rounds and all(m in rounds[0]["towns"][town] for m in ("adapt", "explore", "sysid")):
            wins = sum(it["towns"][town]["adapt"]["tracking_cost"] < min(it["towns"][town]["explore"]["tracking_cost"],
                                                                         it["towns"][town]["sysid"]["tracking_cost"])
                       for it in rounds[1:])
            out.append(f"- {town}: adapt below explore and sysid in tracking cost in {wins} of {len(rounds) - 1} "
                       "online rounds after the first.")
        if "oracle" in s and "adapt" in s:
            gap = ex["tracking_cost_mean"] - s["oracle"]["tracking_cost_mean"]
            if gap > 0.05 * ex["tracking_cost_mean"]:
                closed = (ex["tracking_cost_mean"] - s["adapt"]["tracking_cost_mean"]) / gap
                out.append(f"- {town}: explore→oracle cost gap {gap:.0f}; adapt closes {100 * closed:.0f} % of it.")
            else:
                out.append(f"- {town}: explore→oracle cost gap {gap:.0f} (under 5 % of explore's cost): too small to "
                           "measure how much of it adapt closes.")
    return out


def comparison_table(comparison: dict[str, Any]) -> str:
    """Markdown of :func:`pernav.study.compare.compare`: paired differences to explore with 95 % CIs."""
    lines = ["| town | method | rounds | cost (explore) | explore − method (95 % CI) | gap closed (95 % CI) | gap "
             "closed, rounds with headroom (n) | cost / explore, rounds without | collisions (explore) | explore − method "
             "collisions per episode (95 % CI) | missed turns (explore) | extra m (explore) | steps off explore |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def ci(x: dict[str, Any] | None, pct: bool = False, digits: int = 0) -> str:
        if not x or x["mean"] != x["mean"]:  # NaN: no gap to close
            return "–"
        f = (lambda v: f"{100 * v:.0f} %") if pct else (lambda v: f"{v:+.{digits}f}")
        return f"{f(x['mean'])} [{f(x['low'])}, {f(x['high'])}]"

    for town, methods in comparison.items():
        for method, f in methods.items():
            no_head, left = f.get("relative_cost_no_headroom"), f.get("left_explore")
            def with_explore(key: str, f: dict[str, Any] = f) -> str:
                return f"{f[key]:.0f} ({f.get('explore_' + key, float('nan')):.0f})"

            lines.append(f"| {town} | {method} | {f['rounds']} | {with_explore('tracking_cost')} | "
                         f"{ci(f['explore_minus_method'])} | "
                         f"{ci(f.get('gap_closed'), True)} | {ci(f.get('gap_closed_headroom'), True)} "
                         f"({f.get('headroom_rounds', 0)}) | {'–' if no_head is None else f'{no_head:.2f}'} | "
                         f"{with_explore('collisions')} | {ci(f.get('explore_minus_method_collisions'), digits=3)} | "
                         f"{with_explore('missed_turns')} | "
                         f"{with_explore('extra_distance')} | "
                         f"{'–' if left is None else f'{100 * left:.0f} %'} |")
    return "\n".join(lines)


def write_report(results: dict[str, Any], out: str | Path) -> Path:
    """Write ``out/figures/*.png`` and ``out/report.md``; returns the report's path."""
    out = Path(out)
    figures = out / "figures"
    figures.mkdir(parents=True, exist_ok=True)
    lines = [f"# pernav study: preset `{results['config']['preset']}`", "",
             f"Towns: {', '.join(results['summary'])}; seed {results['config']['seed']}; "
             f"wall time {wall_time(results).get('wall_s', '?')} s.", "",
             "## Collisions per route set (mean (std) over online rounds), tracking cost and completion", "",
             collision_table(results), "", "## Paired comparison with explore (all online rounds' episodes, 95 % "
             "bootstrap CIs)", "", comparison_table(results["comparison"]) if "comparison" in results else "–", "",
             "## Against the paper's headline", "", *_headline(results), ""]
    for town in results["summary"]:
        plot_costs(results, town, figures / f"{town}_cost.png")
        plot_regret(results, town, figures / f"{town}_regret.png")
        lines += [f"## {town}", "", f"![cost](figures/{town}_cost.png)", ""]
        if (figures / f"{town}_regret.png").exists():
            lines += [f"![regret](figures/{town}_regret.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path
