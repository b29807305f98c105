"""The split benchmark's one look (docs/personal.md, "The split benchmark"): the pre-registered figures of the belief
learner on the 16 studies of seeds 100-115.

    for s in $(seq 100 115); do pernav study --preset split --seed $s --out runs/split/seed$s --workers 2; done
    .venv/bin/python docs/research/scripts/split_judge.py runs/split/seed*     # -> docs/figures/split/judged.json
"""

import json
import sys
from pathlib import Path

from pernav.study.headroom import judge_split


def main() -> None:
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in sys.argv[1:]]
    figures = judge_split(runs)
    Path("docs/figures/split/judged.json").write_text(json.dumps(figures, indent=1) + "\n")
    print(json.dumps(figures, indent=1))


if __name__ == "__main__":
    main()
