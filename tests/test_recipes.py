"""The recipes a user copies: each says what it shows and how long it takes, and pool_seeds reports what it claims
(the model and planning diagnostics are pernav.diagnostics modules, tested in tests/diagnostics)."""

from __future__ import annotations

import ast
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _recipe(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "recipes" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _study_results(seed: int, costs: dict[str, list[float]]) -> dict:
    """A minimal results.json: one online round in Town1 with one episode per route for each method."""
    towns = {"Town1": {m: {"episodes": [{"route": r, "tracking_cost": c} for r, c in enumerate(v)]}
                       for m, v in costs.items()}}
    return {"config": {"seed": seed}, "iterations": [{"label": "Online 0", "phase": "online", "towns": towns}]}


@pytest.mark.slow
def test_pool_seeds_pairs_two_protocols_on_the_same_episodes(tmp_path):
    pool = _recipe("pool_seeds")
    a = [_study_results(s, {"explore": [10.0, 20.0, 30.0], "adapt": [8.0, 20.0, 25.0 + s]}) for s in (0, 1)]
    b = [_study_results(s, {"explore": [10.0, 20.0, 30.0], "adapt": [10.0, 21.0, 30.0]}) for s in (0, 1)]
    assert pool.paired_against(a, a, "adapt")["Town1"]["mean"] == 0.0
    got = pool.paired_against(a, b, "adapt")["Town1"]
    diffs = [-2.0, -1.0, -5.0, -2.0, -1.0, -4.0]  # a - b per episode, by hand
    assert got["n"] == 6 and abs(got["mean"] - sum(diffs) / 6) < 1e-12 and got["low"] <= got["mean"] <= got["high"]
    other_seed = [_study_results(5, {"explore": [10.0, 20.0, 30.0], "adapt": [1.0, 2.0, 3.0]})]
    with pytest.raises(ValueError, match="same episodes"):
        pool.paired_against(a[:1], other_seed, "adapt")
    moved = [_study_results(0, {"explore": [11.0, 20.0, 30.0], "adapt": [1.0, 2.0, 3.0]})]
    with pytest.raises(ValueError, match=r"in 1 of 3 episodes \(first: seed 0, Online 0, Town1, route 0: 10.0 vs 11.0\)"
                       r".*not paired"):
        pool.paired_against(a[:1], moved, "adapt")
    for k, r in enumerate(a + moved):  # the CLI: unpaired sets exit 2 and write nothing
        (tmp_path / f"r{k}.json").write_text(json.dumps(r))
    out = tmp_path / "pooled.json"
    run = subprocess.run([sys.executable, str(ROOT / "recipes" / "pool_seeds.py"), str(tmp_path / "r0.json"),
                          "--against", str(tmp_path / "r2.json"), "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 2 and "not paired" in run.stderr and not out.exists()


RECIPES = sorted((ROOT / "recipes").glob("*.py"))


@pytest.mark.parametrize("path", RECIPES, ids=[p.stem for p in RECIPES])
def test_each_recipe_says_what_it_shows_and_how_long_it_takes(path: Path) -> None:
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    assert len(doc.splitlines()) >= 3, f"{path.name}: a module docstring of what it shows"
    assert any(w in doc for w in (" s ", " s)", " s,", " s;", "second", "min", "hour")), f"{path.name}: how long it takes"
