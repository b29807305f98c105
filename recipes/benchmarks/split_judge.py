"""The split benchmark's one look (docs/personal.md, "The split benchmark"): the pre-registered figures of the belief
learner on the 16 studies of seeds 100-115.

    for s in $(seq 100 115); do pernav study --preset split --seed $s --out runs/split/seed$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.split_judge runs/split/seed*     # -> docs/figures/split/judged.json
    (--out FILE writes it elsewhere: the second look writes beside the first)
"""

import json
import sys
from pathlib import Path

from recipes.benchmarks.headroom import judge_split


def main() -> None:
    args, out = sys.argv[1:], Path("docs/figures/split/judged.json")
    if "--out" in args:  # the second look writes beside the first, never over it
        i = args.index("--out")
        out = Path(args[i + 1])
        del args[i: i + 2]
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in args]
    figures = judge_split(runs)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(figures, indent=1) + "\n")
    print(summary(figures))


def _ci(x: dict, scale: float = 1.0, fmt: str = "{:.3f}") -> str:
    return f"{fmt.format(x['mean'] * scale)} [{fmt.format(x['low'] * scale)}, {fmt.format(x['high'] * scale)}]"


def summary(f: dict) -> str:
    """The pre-registered figures in plain lines (docs/personal.md's table is written from them)."""
    slow, quick = f["late"], f["on_time"]
    lines = [f"seeds {f['seeds'][0]}-{f['seeds'][-1]} ({len(f['seeds'])})",
             f"slow half: {slow['learner_episodes']} episodes; explore {slow['explore']:.1f}, oracle {slow['oracle']:.1f}, "
             f"belief {slow['learner']:.1f}; oracle gain {_ci(slow['oracle_gain'], 1, '{:+.1f}')}; "
             f"gap closed {_ci(slow['gap_closed'], 100, '{:.0f}')} %"]
    for town, t in slow.get("per_town", {}).items():
        closed = _ci(t["gap_closed"], 100, "{:.0f}")
        lines.append(f"  {town}: explore {t['explore']:.1f}, oracle {t['oracle']:.1f}, belief {t['learner']:.1f}, "
                     f"oracle gain {_ci(t['oracle_gain'], 1, '{:+.1f}')}, gap closed {closed} %")
    lines.append(f"quick half: {quick['learner_episodes']} episodes; explore {quick['explore']:.1f}, oracle "
                 f"{quick['oracle']:.1f}, belief {quick['learner']:.1f}; belief / explore {_ci(quick['cost_ratio'])}")
    if "quick_turn_lead" in f:
        lines.append(f"quick half: belief's turn lead minus explore's {_ci(f['quick_turn_lead'], 1, '{:+.2f}')} s")
    for name in ("all", "quick", "slow"):
        key = f"{name}_against_timing"
        if key in f:
            lines.append(f"{name} cells: belief / timing {_ci(f[key]['ratio'])}; timing - belief "
                         f"{_ci(f[key]['difference'], 1, '{:+.1f}')}")
    c = f["collisions"]
    lines.append(f"collisions: explore {c['explore']:.0f}, belief {c['learner']:.0f}; belief - explore per episode "
                 f"{_ci(c['learner_minus_explore'], 1, '{:+.3f}')}")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
