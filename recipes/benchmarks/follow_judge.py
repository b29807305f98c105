"""Three follow-up looks at the belief learner, each run once on the seeds pre-registered in
docs/figures/follow/preregistration.json (recipes/benchmarks/follow.py): the sweep's "turn" leads, the personalization
curve over repeated drives, the headroom benchmark on fresh seeds.

    for s in 200 201 202 203; do pernav study --preset personal_sweep --methods explore timing belief oracle \
        --seed $s --out runs/follow/sweep/seed$s --workers 2; done
    for s in 400 401 402 403; do pernav study --preset repeat --seed $s --out runs/follow/repeat/seed$s --workers 2; done
    for s in 300 301 302 303 304 305; do pernav study --preset personal --methods explore timing belief oracle \
        --seed $s --out runs/follow/headroom/seed$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.follow_judge sweep runs/follow/sweep/seed*
    .venv/bin/python -m recipes.benchmarks.follow_judge repeat runs/follow/repeat/seed*
    .venv/bin/python -m recipes.benchmarks.follow_judge headroom runs/follow/headroom/seed*

Each writes docs/figures/follow/<look>.json (and the sweep's and the curve's .png) and prints the figures; ``--out DIR``
writes them to DIR instead (the second look: docs/figures/follow/second).
"""

import json
import sys
from pathlib import Path

from recipes.benchmarks import follow

OUT = Path("docs/figures/follow")


def _ci(x: dict, scale: float = 1.0, fmt: str = "{:.3f}") -> str:
    return f"{fmt.format(x['mean'] * scale)} [{fmt.format(x['low'] * scale)}, {fmt.format(x['high'] * scale)}]"


def sweep(runs: list[dict]) -> list[str]:
    j = follow.judge_sweep(runs)
    j["plot"] = follow.plot_sweep_leads(runs, str(OUT / "sweep_leads.png"))
    (OUT / "sweep.json").write_text(json.dumps(j, indent=1) + "\n")
    lines = follow.sweep_lines(j)
    for name in ("pooled", "Town1", "Town3"):
        r = j.get(name, {})
        if "quick_end_cost_ratio" in r:
            lines.append(f"{name}: quick end belief / explore {_ci(r['quick_end_cost_ratio'])}; slow end gap closed "
                         f"{_ci(r['slow_end_gap_closed'], 100, '{:.0f}')} % ({r['slow_end']})")
    return lines


def repeat(runs: list[dict]) -> list[str]:
    j = follow.judge_repeat(runs)
    follow.plot_personalization(j, str(OUT / "personalization.png"))
    (OUT / "repeat.json").write_text(json.dumps(j, indent=1) + "\n")
    lines = [f"seeds {j['seeds']}"]
    for k, r in j["drives"].items():
        parts = [f"drive {k}:"]
        if "slow_gap_closed" in r:
            parts.append(f"slow gap closed {_ci(r['slow_gap_closed'], 100, '{:.0f}')} % ({r['slow']})")
        if "quick_cost_ratio" in r:
            parts.append(f"quick / explore {_ci(r['quick_cost_ratio'])}")
        if "quick_turn_lead" in r:
            parts.append(f"quick lead - explore's {_ci(r['quick_turn_lead'], 1, '{:+.2f}')} s")
        if "interval_width" in r:
            parts.append(f"90% interval width {r['interval_width']:.2f} s, |log error| {r['abs_log_error']:.3f}")
        lines.append("; ".join(parts))
    return lines


def headroom(runs: list[dict]) -> list[str]:
    j = follow.judge_headroom_fresh(runs)
    (OUT / "headroom.json").write_text(json.dumps(j, indent=1) + "\n")
    lines = [f"seeds {j['learner']['seeds']}"]
    for who in ("learner", "baseline"):
        r = j[who]
        late, on = r["late"], r["on_time"]
        lines.append(f"{r['learner']}: late gap closed {_ci(late['gap_closed'], 100, '{:.0f}')} % (explore "
                     f"{late['explore']:.1f}, oracle {late['oracle']:.1f}, it {late['learner']:.1f}); on time / explore "
                     f"{_ci(on['cost_ratio'])}; collisions {r['collisions']['learner']:.0f} vs explore "
                     f"{r['collisions']['explore']:.0f}, per episode {_ci(r['collisions']['learner_minus_explore'])}")
        for town, t in late.get("per_town", {}).items():
            lines.append(f"  late {town}: gap closed {_ci(t['gap_closed'], 100, '{:.0f}')} %, oracle gain "
                         f"{_ci(t['oracle_gain'], 1, '{:+.1f}')}")
    if "late_minus_baseline" in j:
        lines.append(f"late: (belief - timing) / gap {_ci(j['late_minus_baseline'], 100, '{:+.1f}')} %")
    return lines


def main() -> None:
    global OUT
    args = sys.argv[1:]
    if "--out" in args:  # the second look writes beside the first, never over it
        i = args.index("--out")
        OUT = Path(args[i + 1])
        del args[i: i + 2]
    look, paths = args[0], args[1:]
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in paths]
    OUT.mkdir(parents=True, exist_ok=True)
    print("\n".join({"sweep": sweep, "repeat": repeat, "headroom": headroom}[look](runs)))


if __name__ == "__main__":
    main()
