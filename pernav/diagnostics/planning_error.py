"""Planning error apart from model error: planners on the true simulator vs explore and the oracle.

A diagnostic of the planner (docs/planning.md, "Planning error"). The run docs/planning.md shows (``--routes 3
--paper-routes 0 --samples 1 --workers 2``) takes about 6 minutes on a 2-core laptop CPU; each true-model
decision steps the full simulator, so an episode takes 1-5 minutes of one core, and the paper planner's episodes
(``--paper-routes``) longer.

Every panel driver (:data:`pernav.diagnostics.panel.PANEL`: named users with headroom, a fast keyboard
driver, population samples) drives the same episodes (route r with seed 1000 + r) in Town1 and Town3 with:

* ``explore`` and ``oracle`` (the rules timed for the average driver / for the true driver);
* ``retime@true``: pernav's default planner on the true simulator (:class:`pernav.diagnostics.TrueDynamicsEnv`:
  re-seeded copies of the live env, averaged), i.e. no model error: its loss to the oracle is planning error;
* ``paper@true``: the paper's planner (horizon 5, masked tree, explore bonus) on the same true simulator.

Model error is the rest: a study's learner (the same planner on the learned, adapted model; ``pernav study``)
against ``retime@true`` (``PanelJob`` also drives ``"retime@learned"`` given a model and its parameters).
Paired differences to explore carry 95 % bootstrap CIs. Results are written as jobs finish.

``--planner-option KEY=VALUE`` (repeatable, as in ``pernav study``) drives the retime planner with other options
on the true simulator too, as its own method ``retime[KEY=VALUE ...]@true``; with ``--resume`` on an earlier
``--json`` only the new method's episodes run, paired with the kept ones. The file records the retime defaults
its ``retime@true`` episodes were driven with; ``--resume`` refuses (exit 2) to add ``retime@true`` episodes
under other defaults (files from before 2026-11-24 record none and used ``delay`` 3).

Run (or ``pernav diagnose planning ...``, the same options):
OMP_WAIT_POLICY=PASSIVE .venv/bin/python -m pernav.diagnostics.planning_error [--routes 5] [--paper-routes 2]
[--samples 1] [--workers 2] [--drivers LABEL ...] [--json docs/figures/planning_error.json] [--resume]
[--plot PNG] [--planner-option KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from itertools import cycle, product
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter
from tqdm import tqdm

from pernav.diagnostics.panel import PANEL, PanelJob, comparison_table, drive_panel_episode, episode_key
from pernav.planner.factory import PLANNER_DEFAULTS, parse_planner_options

TOWNS = ("Town1", "Town3")


def scatter(episodes: list[dict], path: str) -> None:
    """Each method's cost against explore's on the same episode (log-log, one panel per town).

    Points below the diagonal beat explore on that episode; pairing per episode lets methods that drove fewer
    routes (``paper@true``) share the figure without comparing different episodes.
    """
    matplotlib.use("Agg")  # headless
    explore = {episode_key(e): e["tracking_cost"] for e in episodes if e["method"] == "explore"}
    methods = [m for m in dict.fromkeys(e["method"] for e in episodes) if m != "explore"]
    fig, axes = plt.subplots(1, len(TOWNS), figsize=(5 * len(TOWNS), 4.4), squeeze=False)
    for ax, town in zip(axes[0], TOWNS, strict=True):
        for method, marker in zip(methods, cycle("o^sDv"), strict=False):
            pairs = [(explore[k], e["tracking_cost"]) for e in episodes
                     if e["method"] == method and e["town"] == town and (k := episode_key(e)) in explore]
            if pairs:
                x, y = zip(*pairs, strict=True)
                ax.scatter(x, y, marker=marker, alpha=0.7, label=f"{method} ({len(pairs)})")
        lo, hi = ax.get_xlim()[0], max(ax.get_xlim()[1], ax.get_ylim()[1])
        ax.plot([lo, hi], [lo, hi], "k:", lw=1)
        ax.set(xscale="log", yscale="log", xlabel="explore's tracking cost", ylabel="method's tracking cost",
               title=f"{town}: per episode; below the diagonal beats explore")
        for axis in (ax.xaxis, ax.yaxis):  # plain numbers; minor log labels would overlap
            axis.set_major_locator(LogLocator(subs=(1, 2, 5)))
            axis.set_major_formatter(ScalarFormatter())
            axis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# options the retime planner had once and dropped (measured, not used), at the values that left them off
_REMOVED = {"rescue": None, "rescue_evidence": True, "route_goals": False}


def _same_defaults(recorded: dict | None, current: dict) -> bool:
    """Were ``recorded`` defaults the ``current`` ones? An option added after the file was written is off by
    default, so a file without it drove as the current defaults do; a removed option recorded off did nothing."""
    if recorded is None:
        return False
    kept = {k: v for k, v in recorded.items() if k not in _REMOVED or v != _REMOVED[k]}
    return {**current, **kept} == current


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """The command line (``argv``: its arguments, default ``sys.argv[1:]``); bad input exits 2 (``SystemExit``)."""
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    ap.add_argument("--routes", type=int, default=5, help="routes 0..N-1 of each town")
    ap.add_argument("--paper-routes", type=int, default=2, help="routes for paper@true (slow: a full tree)")
    ap.add_argument("--samples", type=int, default=1, help="re-seeded simulator copies per imagination")
    ap.add_argument("--drivers", nargs="*", default=list(PANEL), help="panel labels")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default="planning_error.json")
    ap.add_argument("--resume", action="store_true", help="keep the episodes already in --json")
    ap.add_argument("--plot", default=None, help="scatter of each episode's cost vs explore's "
                    "(default: --json with .png)")
    ap.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                    help="also drive retime@true with these options (pernav.planner.PLANNER_DEFAULTS); repeatable")
    args = ap.parse_args(argv)
    bad = [d for d in args.drivers if d not in PANEL]
    if bad:
        ap.error(f"unknown driver {bad[0]!r}; choose from {', '.join(PANEL)}")
    try:
        options = parse_planner_options("retime", args.planner_option)
    except ValueError as exc:
        ap.error(f"--planner-option {exc}")
    variant = f"retime[{' '.join(args.planner_option)}]@true"  # its label in the episodes
    jobs = [PanelJob(d, t, r, 1000 + r, m, samples=args.samples)
            for m in ("explore", "oracle", "retime@true") for d, t, r in product(args.drivers, TOWNS, range(args.routes))]
    jobs += [PanelJob(d, t, r, 1000 + r, "paper@true", samples=args.samples)
             for d, t, r in product(args.drivers, TOWNS, range(args.paper_routes))]
    labels = {id(j): j.method for j in jobs}
    if options:
        variants = [PanelJob(d, t, r, 1000 + r, "retime@true", samples=args.samples, planner=options)
                    for d, t, r in product(args.drivers, TOWNS, range(args.routes))]
        labels.update({id(j): variant for j in variants})
        jobs += variants
    episodes, defaults = [], PLANNER_DEFAULTS["retime"]  # what "retime@true" means in this file
    if args.resume and Path(args.json).is_file():  # keep finished episodes, run only the missing ones
        kept = json.loads(Path(args.json).read_text())
        episodes = kept["episodes"]
        done = {(*episode_key(e), e["method"]) for e in episodes}
        jobs = [j for j in jobs if (j.driver, j.town, j.route, j.seed, labels[id(j)]) not in done]
        if any(e["method"] == "retime@true" for e in episodes):
            # a file written before the record (None) used other defaults: delay was 3 until 2026-11-24
            defaults = kept.get("planner_defaults")
            adding = any(labels[id(j)] == "retime@true" for j in jobs)
            if adding and not _same_defaults(defaults, PLANNER_DEFAULTS["retime"]):
                ap.error(f"--resume: {args.json}'s retime@true episodes were driven with the retime defaults "
                         f"{defaults} (null: not recorded, delay 3 before 2026-11-24), now "
                         f"{PLANNER_DEFAULTS['retime']}; adding episodes would mix the two under one label. "
                         "Use a new --json, or --planner-option for a labelled variant with the options you want")
    with ProcessPoolExecutor(args.workers) as pool:
        futures = {pool.submit(drive_panel_episode, j): labels[id(j)] for j in jobs}
        for f in tqdm(as_completed(futures), total=len(futures), desc="episodes"):
            episodes.append({**f.result(), "method": futures[f]})
            with open(args.json, "w") as fh:
                json.dump({"drivers": {d: PANEL[d] for d in args.drivers}, "planner_defaults": defaults,
                           "episodes": episodes}, fh, indent=1)
    print(comparison_table(episodes))
    scatter(episodes, args.plot or str(Path(args.json).with_suffix(".png")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
