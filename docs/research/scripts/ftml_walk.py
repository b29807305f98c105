"""Does FTML (``meta_train``) follow the meta leader over a finished study's rounds? Replays ``adapt_driver``'s meta
training on the study's stored ``(tau, other drives)`` pairs (the offline halves, then one online round at a time, as
the study did) and prints ``P`` and FTML's objective (:func:`~pernav.learners.driver.meta_loss`) over the pairs so
far after each; ``--unguarded`` keeps Adam's result even where it scores worse than the start (the code before the
ninth session). Pairs read by the tracker under the study's own ``P`` at the time, so a replay is close, not exact.

    .venv/bin/python docs/research/scripts/ftml_walk.py --study runs/look_sweep_s232 --town Town3 --unguarded
"""

from __future__ import annotations

import argparse
from unittest import mock

import torch

from pernav.learners import driver as learner
from pernav.learners.driver import DriverPrior, Evidence, meta_loss, meta_train
from pernav.study.finished import FinishedStudy


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--study", required=True, help="a finished study that ran adapt_driver")
    ap.add_argument("--town", default="Town1")
    ap.add_argument("--unguarded", action="store_true", help="keep Adam's result even where it scores worse")
    args = ap.parse_args()
    torch.set_num_threads(1)
    data = FinishedStudy.open(args.study).driver_state(args.town).data
    p0 = DriverPrior.from_dict(data["prior0"])
    offline = [(Evidence.from_state(a), Evidence.from_state(b)) for a, b in data["offline_pairs"]]
    online = [(Evidence.from_state(a), Evidence.from_state(b)) for a, b in data["online_pairs"]]

    def show(name: str, prior: DriverPrior, pairs: list) -> None:
        print(f"{name:18s} centre (log R, D) {[round(x, 3) for x in prior.mean]}, spread {[round(x, 3) for x in prior.sd]}, "
              f"FTML's objective {meta_loss(prior, pairs):.4f} per item")

    # unguarded: the objective never looks worse, so Adam's result is always kept
    patch = mock.patch.object(learner, "meta_loss", side_effect=[0.0, 1.0] * 1000) if args.unguarded else mock.MagicMock()
    with patch:
        show("P0", p0, offline)
        prior = meta_train(p0, offline)
        show("P offline", prior, offline)
        for i in range(len(online)):
            prior = meta_train(prior, offline + online[: i + 1], steps=20, seed=i + 1)
            show(f"P after online {i + 1}", prior, offline + online[: i + 1])


if __name__ == "__main__":
    main()
