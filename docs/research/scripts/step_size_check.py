"""How long should the adaptation step be? Held-out loss against U's step size, at online time.

Runs the default study (methods explore and adapt, the paper's fixed step) in each town and seed, and in every
online round, just before the round's training (the moment the study scores adaptation), records for each
ensemble member and each step in ``STEPS``: the held-out L-step loss of the round (tau and calibration drives
left out), the loss on tau itself, and a 2-fold loss on tau (adapt on one half in time, score the other). Then
it compares rules for the step: fixed steps, and the sufficient-decrease (Armijo) backtracking from alpha
that ``train.backtrack`` uses, for several constants c. Printed and written to ``--json``.

Measured on world v1 (seeds 0-2, Town1 and Town3, 36 rounds; 4cd6bc4:docs/figures/planning/step_size.json): the paper's alpha
0.01 lowers the held-out loss in 27 of 36 rounds (mean ratio to unadapted 0.952), alpha 0.005 in 31 (0.933),
Armijo c=0.5 from alpha in 31 (0.923, the lowest mean). See docs/research/findings.md, "One step, how long?".

Run: .venv/bin/python docs/research/scripts/step_size_check.py --seeds 0 1 2 --towns Town1 Town3 --out runs/step_size \
    --json FILE  (about 4 min per town and seed)
     .venv/bin/python docs/research/scripts/step_size_check.py --summarize runs/step_size --json FILE  (no new runs)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import torch

from pernav.model.adapt import adapt, trajectory_windows
from pernav.model.losses import multistep_loss
from pernav.study import runner
from pernav.study.config import preset
from pernav.trainer.ensemble import EnsembleTrainer

STEPS = [0.0, 0.00125, 0.0025, 0.005, 0.01, 0.02]  # 0: unadapted; 0.01 is alpha (the paper's)
ALPHA_INDEX = 4


def _adapted(member: Any, data: Any, step: float) -> Any:
    if not step:
        return None
    cfg = member.config
    with torch.enable_grad():
        return adapt(member.model, data, alpha=step, L=cfg.L, first_order=True, max_norm=cfg.max_grad_norm).detach()


def _loss(member: Any, data: Any, params: Any) -> float:
    with torch.no_grad():
        return float(multistep_loss(member.model, trajectory_windows(data, member.config.L, member.config.L),
                                    params=params))


def round_row(trainer: EnsembleTrainer, round_: int) -> dict[str, Any]:
    """Every member's held-out, tau and 2-fold losses over ``STEPS``, and its adaptation gradient norm."""
    tau = trainer.buffers.tau(round_)
    half = tau.shape[0] // 2
    members = []
    for m in trainer.members:
        grads = torch.autograd.grad(multistep_loss(m.model, trajectory_windows(tau, m.config.L, m.config.L)),
                                    list(m.model.parameters()))
        row: dict[str, Any] = {"gnorm": float(torch.sqrt(sum((g ** 2).sum() for g in grads))),
                               "held": [], "tau": [], "cv": []}
        for step in STEPS:
            params = _adapted(m, tau, step)
            row["held"].append(m.round_loss(round_, params is not None, params))
            row["tau"].append(_loss(m, tau, params))
            row["cv"].append(_loss(m, tau[half:], _adapted(m, tau[:half], step))
                             + _loss(m, tau[:half], _adapted(m, tau[half:], step)))
        members.append(row)
    return {"round": round_, "members": members}


def run(town: str, seed: int, out: Path) -> list[dict[str, Any]]:
    """One town and seed of the default study (explore and adapt, fixed step); a row per online round."""
    rows: list[dict[str, Any]] = []
    scored = EnsembleTrainer.round_loss

    def recording(self: EnsembleTrainer, round_: int, adapted: bool, params: Any = None) -> float:
        if adapted and params is None:  # the study's adaptation check of an online round: record first
            rows.append(round_row(self, round_))
        return scored(self, round_, adapted, params)

    cfg = preset("default")
    cfg.seed, cfg.towns, cfg.methods = seed, [town], ["explore", "adapt"]
    cfg.train.backtrack = None  # the models of a fixed-step study; the rules are compared on them
    EnsembleTrainer.round_loss = recording  # the study scores adaptation here; no other hook is needed
    try:
        runner.run_town(cfg, town, out / f"{town}_{seed}")
    finally:
        EnsembleTrainer.round_loss = scored
    return rows


def _armijo(c: float):
    def choose(m: dict[str, Any]) -> int:
        for k in range(ALPHA_INDEX, 0, -1):  # alpha, alpha/2, alpha/4, alpha/8 (as pernav.model.adapt)
            if m["tau"][k] <= m["tau"][0] - c * STEPS[k] * min(m["gnorm"], 100.0) ** 2:
                return k
        return 1
    return choose


def _fixed(k: int):
    return lambda m: k


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per rule: rounds where the ensemble's mean held-out loss is below the unadapted one, and the mean ratio."""
    rules = {f"fixed {s}": _fixed(k) for k, s in enumerate(STEPS) if s}
    rules.update({f"armijo c={c}": _armijo(c) for c in (0.25, 0.5, 0.75)})
    rules["2-fold on tau"] = lambda m: min(range(1, len(STEPS)), key=lambda k: m["cv"][k])

    def held(row: dict[str, Any], choose: Any) -> float:
        return sum(m["held"][choose(m)] for m in row["members"]) / len(row["members"])

    out = {}
    for name, choose in rules.items():
        ratios = [held(r, choose) / held(r, _fixed(0)) for r in rows]
        out[name] = {"lowered": sum(x < 1 for x in ratios), "rounds": len(rows),
                     "mean_ratio": round(sum(ratios) / len(ratios), 3)}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--towns", nargs="+", default=["Town1", "Town3"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", type=Path, help="folder for the study runs and rows.json")
    parser.add_argument("--summarize", type=Path, help="a folder of an earlier run: summarize its rows.json")
    parser.add_argument("--json", type=Path, help="write the rows and the summary here")
    args = parser.parse_args(argv)
    if args.summarize is not None:
        source = args.summarize / "rows.json"
        if not source.is_file():
            print(f"error: --summarize {args.summarize}: no rows.json there (run without --summarize first)",
                  file=sys.stderr)
            return 2
        rows = json.loads(source.read_text())
    elif args.out is None:
        print("error: --out is required (or --summarize FOLDER)", file=sys.stderr)
        return 2
    else:
        torch.set_num_threads(1)
        rows = []
        for seed in args.seeds:
            for town in args.towns:
                rows += [{"town": town, "seed": seed, **r} for r in run(town, seed, args.out)]
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "rows.json").write_text(json.dumps(rows))
    summary = summarize(rows)
    for name, s in summary.items():
        print(f"{name:16s} lowers the held-out loss in {s['lowered']}/{s['rounds']} rounds, "
              f"mean held-out / unadapted {s['mean_ratio']}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"steps": STEPS, "summary": summary, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
