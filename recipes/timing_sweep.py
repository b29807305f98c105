"""Timing sweep for docs/simulator.md: outcomes and tracking cost vs the lead time of one "turn" prompt.

Shows why a prompt's timing must be personal: the best lead differs by seconds between drivers. Takes about 40 s
with ``--seeds 6`` on a 2-core laptop CPU (the default 10 seeds: about a minute).

The world draws each prompt's reaction time, so every lead is driven with several seeds (the same seeds at
every lead) and the figure shows the share of each outcome and the mean tracking cost; the best lead is the
shortest lead whose mean cost is within 1 % of the cheapest among the leads clean for at least 80 % of the seeds.

Run: .venv/bin/python recipes/timing_sweep.py docs/figures/timing_sweep.png [--seeds 10] [--json FILE]
"""

import argparse
import json

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pernav.env.sweep import best_seeded_lead, seeded_sweep  # noqa: E402
from pernav.world.drivers import Context, named_user  # noqa: E402

PROFILES = {
    "fast, aggressive, keyboard (user4)": (named_user("user4"), Context(equipment="keyboard")),
    "experienced (user1)": (named_user("user1"), Context()),
    "average driver, cybertruck (user7)": (named_user("user7"), Context(vehicle="cybertruck")),
    "slow reactions, fog, cybertruck (user3)": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
}
COLOR = {"clean": "tab:green", "harsh": "tab:orange", "strike": "tab:red", "missed": "tab:purple",
         "forgot": "tab:gray", "wrong": "tab:brown"}


def main(out: str, seeds: int, json_out: str | None) -> None:
    leads = np.arange(0.0, 16.5, 1.0)
    fig, axes = plt.subplots(len(PROFILES), 1, figsize=(8, 9), sharex=True)
    doc = {}
    for ax, (name, (p, c)) in zip(axes, PROFILES.items(), strict=True):
        rows = seeded_sweep(p, c, leads=leads, seeds=range(seeds))
        best = best_seeded_lead(rows)
        bottom = np.zeros(len(rows))
        for k, col in COLOR.items():
            share = np.array([r["shares"].get(k, 0.0) for r in rows])
            ax.bar(leads, share, bottom=bottom, color=col, width=0.8, label=k)
            bottom += share
        twin = ax.twinx()
        twin.plot(leads, [r["tracking_cost"] for r in rows], "k.-", lw=1)
        twin.set_yscale("log")
        twin.set_ylabel("mean tracking cost", fontsize=8)
        ax.axvline(best, color="k", ls="--", lw=1)
        ax.set_title(f"{name}: best lead {best:.0f} s", fontsize=9)
        ax.set_ylabel("share of seeds")
        doc[name] = {"best_lead": best, "rows": rows}
        print(name, "best", best, [(r["lead"], r["shares"]) for r in rows])
    axes[0].legend(fontsize=7, ncol=6, loc="upper center", bbox_to_anchor=(0.5, 1.45))
    axes[-1].set_xlabel('lead time of the single "turn right" before the junction (s)')
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    if json_out:
        with open(json_out, "w") as f:
            json.dump({"seeds": seeds, "profiles": doc}, f, indent=1)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="timing_sweep.png")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    main(args.out, args.seeds, args.json)
