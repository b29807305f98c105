"""Timing sweep figure for docs/simulator.md: outcome and tracking cost vs lead time of one "turn".

Run: .venv/bin/python recipes/timing_sweep.py docs/figures/timing_sweep.png
"""

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pernav.env.sweep import best_lead, timing_sweep  # noqa: E402
from pernav.world.drivers import Context, named_user  # noqa: E402

PROFILES = {
    "fast, aggressive, keyboard (user4)": (named_user("user4"), Context(equipment="keyboard")),
    "experienced (user1)": (named_user("user1"), Context()),
    "slow reactions, fog, cybertruck (user3)": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
}
MARK = {"clean": ("o", "tab:green"), "harsh": ("s", "tab:orange"), "strike": ("X", "tab:red"),
        "missed": ("v", "tab:purple"), "forgot": ("^", "tab:gray"), "wrong": ("D", "tab:brown")}


def main(out: str) -> None:
    fig, axes = plt.subplots(len(PROFILES), 1, figsize=(8, 7), sharex=True)
    for ax, (name, (p, c)) in zip(axes, PROFILES.items(), strict=True):
        rows = timing_sweep(p, c, leads=np.arange(0.0, 16.5, 1.0))
        for r in rows:
            m, col = MARK[r["outcome"]]
            ax.scatter(r["lead"], r["tracking_cost"], marker=m, color=col, s=45)
        best = best_lead(rows)
        ax.axvline(best, color="k", ls="--", lw=1)
        ax.set_yscale("log")
        ax.set_title(f"{name}: best lead {best:.0f} s", fontsize=9)
        ax.set_ylabel("tracking cost")
        print(name, best, [(r["lead"], r["outcome"]) for r in rows])
    for k, (m, col) in MARK.items():
        axes[0].scatter([], [], marker=m, color=col, label=k)
    axes[0].legend(fontsize=7, ncol=6, loc="upper center")
    axes[-1].set_xlabel('lead time of the single "turn right" before the junction (s)')
    fig.tight_layout()
    fig.savefig(out, dpi=110)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "timing_sweep.png")
