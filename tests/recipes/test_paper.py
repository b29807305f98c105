"""docs/paper.md from compact per-town results: compaction keeps the figures, the table, the claims, the commands."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from study_helpers import smoke_study

from pernav.study.compare import compare
from pernav.study.study import summarize
from recipes.benchmarks.paper import (
    BEGIN,
    END,
    PAPER_TABLE1,
    PaperError,
    claims,
    compact,
    expand,
    generated_section,
    main,
    merge,
    paper_markdown,
    town_table,
)

ROOT = Path(__file__).resolve().parents[2]
LATEX = ROOT / "tests" / "data" / "paper_safety_tables.tex"  # the paper's two collision tables, verbatim
METHODS = ("explore", "sysid", "adapt", "adapt_speed", "hindsight", "oracle")
Figure = Callable[[str, int, int], float]


def synthetic(town: str = "Town2", seed: int = 0, rounds: int = 15, routes: int = 2, cost: Figure | None = None,
              hits: Figure | None = None, methods: tuple[str, ...] = METHODS) -> dict:
    """A results.json as the study writes it: ``cost(method, round, route)`` and ``hits(method, round, route)``
    give each episode's tracking cost and collisions (defaults: explore 100, the learners cheaper, no collisions)."""
    cost = cost or (lambda m, k, r: {"explore": 100.0, "sysid": 95.0}.get(m, 80.0) + r)
    hits = hits or (lambda m, k, r: 0)

    def episode(m: str, k: int, r: int) -> dict:
        c, h = cost(m, k, r), int(hits(m, k, r))
        return {"route": r, "tracking_cost": c, "vehicle_collisions": h, "edge_strikes": 0, "collisions": h,
                "missed_turns": int(c > 150), "wrong_turns": 0, "extra_distance": 0.0, "completed": True,
                "steps": 100, "turn_lead": 5.0, "left_explore": 0.0 if m == "explore" else 0.25}

    def figures(m: str, k: int) -> dict:
        eps = [episode(m, k, r) for r in range(routes)]
        return {"tracking_cost": sum(e["tracking_cost"] for e in eps) / routes,
                "collisions": sum(e["collisions"] for e in eps), "vehicle_collisions": sum(e["collisions"] for e in eps),
                "edge_strikes": 0, "completion": 1.0, "episodes": eps}

    user = {"name": "user1", "profile": {"reaction_time": 0.9}, "context": {"vehicle": "camaro"}}
    its = [{"label": "Offline 0", "phase": "offline", "user": user, "towns": {town: {"explore": figures("explore", -1)}}}]
    its += [{"label": f"Online {k}", "phase": "online", "user": user, "towns": {town: {m: figures(m, k) for m in methods}}}
            for k in range(rounds)]
    online = [it["towns"][town] for it in its[1:]]
    regret = [r["adapt"]["tracking_cost"] - r["hindsight"]["tracking_cost"] for r in online if "hindsight" in r]
    return {"config": {"preset": "paper", "towns": [town], "routes": routes, "rollouts": 4, "seed": seed},
            "iterations": its, "summary": summarize(its), "comparison": compare([its]),
            "regret": {town: {"labels": [it["label"] for it in its[1:]], "cost_regret": regret,
                              "loss_regret": [1.0 / (k + 1) for k in range(rounds)]}},
            "diagnostics": {town: {}},
            "wall_time": {"wall_s": 60.0, "workers": 2, "towns": {town: {it["label"]: 30.0 for it in its}},
                          "profile": {town: {"evaluation_s": 40.0}}}}


def _claim(merged: dict, start: str):
    return next(c for c in claims(merged) if c.text.startswith(start))


def check_compact_keeps_the_figures(results: dict) -> None:
    """What docs/paper.md reads from a compact town (after a JSON round trip) is what the results.json says."""
    for town in results["summary"]:
        small = json.loads(json.dumps(compact(results, town)))
        assert compare([expand(small)])[town] == results["comparison"][town]  # paired differences and their CIs
        table = town_table(small)
        for m, s in results["summary"][town].items():
            for key in ("collisions_mean", "collisions_std", "tracking_cost_mean", "completion_mean"):
                assert table[m][key] == pytest.approx(s[key], abs=1e-12), (m, key)
            if m != "explore":
                assert table[m]["explore_minus_method"] == results["comparison"][town][m]["explore_minus_method"]
        assert small["regret"] == results["regret"][town]


def test_the_papers_collisions_are_transcribed_from_its_latex():
    text = LATEX.read_text()
    rows = {"explore": r"Explore policy", "sysid": r"SysID[^&]*", "adapt": r"Adapt(?:ive)?\s+\(Ours\)",
            "adapt_speed": r"Adapt(?:ive)?\s+Speed\s+\(Ours\)"}
    cell = r"&\s*([\d.]+) \(([\d.]+)\)\s*"
    for towns, label in ((("Town1", "Town2", "Town3"), "table:safety"), (("Town4", "Town5"), "app:table:safety")):
        block = text[:text.index(r"\label{" + label + "}")].rsplit(r"\begin{tabular}", 1)[1]
        for method, name in rows.items():
            found = re.search(name + r"\s*" + cell * len(towns), block).groups()
            for i, town in enumerate(towns):
                assert PAPER_TABLE1[town][method] == (float(found[2 * i]), float(found[2 * i + 1])), (town, method)


def test_compact_keeps_the_figures_of_a_synthetic_study():
    results = synthetic(cost=lambda m, k, r: 100.0 + 7 * ((k * 3 + r * 5 + len(m)) % 11),
                        hits=lambda m, k, r: (k + r) % 3 == 0)
    check_compact_keeps_the_figures(results)
    small = compact(results)
    assert "comparison" not in small and "steps" not in small["rounds"][1]["methods"]["adapt"]["episodes"]


@pytest.mark.slow
def test_compact_keeps_the_figures_of_the_smoke_study(tmp_path_factory):
    out = smoke_study(tmp_path_factory)
    results = json.loads((out / "results.json").read_text())
    check_compact_keeps_the_figures(results)
    # its towns' compacts together: 43 % of the shared smoke study's results.json (Town1 and Town2; 41 % for Town1
    # alone; its config and diagnostics weigh most); 20 % at the paper's size
    small = sum(len(json.dumps(compact(results, town), separators=(",", ":"))) for town in results["summary"])
    assert len(results["summary"]) == 2 and small < 0.5 * (out / "results.json").stat().st_size


def test_the_table_of_a_known_input():
    results = synthetic(rounds=2, cost=lambda m, k, r: {"explore": 100.0, "sysid": 95.0}.get(m, 80.0),
                        hits=lambda m, k, r: {"explore": 1, "sysid": k == 0}.get(m, 0))
    page = paper_markdown(merge([compact(results)]))
    town2 = page.split("### Town2")[1].split("###")[0]
    assert "| explore | 1.00 (1.18) | 2.00 (0.00) | 100 | 100 % | 0 | – | – |" in town2
    assert "| adapt | 0.31 (0.61) | 0.00 (0.00) | 80 | 100 % | 0 | +20 [+20, +20] | +1.000 [+1.000, +1.000] |" in town2
    assert "| sysid | 0.69 (1.14) | 1.00 (1.00) | 95 | 100 % | 0 | +5 [+5, +5] |" in town2
    assert "| oracle | – | 0.00 (0.00) | 80 |" in town2  # every method the study ran, not only the paper's
    assert "| timing |" not in town2
    assert "Preset `paper`, seed 0, 2 online rounds (paper: 15), 2 routes" in town2


def test_files_from_before_the_wall_time_rename_read_the_same():
    def renamed(d: dict) -> dict:  # as written when the wall time was called "timing"
        return {("timing" if k == "wall_time" else k): v for k, v in d.items()}

    results = synthetic(rounds=2)
    assert compact(renamed(results))["wall_time"] == compact(results)["wall_time"]  # an old results.json
    small = compact(results)
    page = paper_markdown(merge([small]))
    assert "last run 60.0 s, 2 workers" in page
    assert paper_markdown(merge([renamed(small)])) == page  # an old compact town


def test_each_claim_flips_with_the_data():
    def judged(**kwargs) -> dict:
        return merge([compact(synthetic(**kwargs))])

    half = judged(hits=lambda m, k, r: {"explore": 1, "adapt": r == 0}.get(m, 0))
    same = judged(hits=lambda m, k, r: {"explore": 1, "adapt": 1}.get(m, 0))
    assert _claim(half, "Adapt ≈").holds and "-50 %" in _claim(half, "Adapt ≈").figure
    assert _claim(same, "Adapt ≈").holds is False
    assert _claim(judged(), "Adapt ≈").holds is False  # explore never collided: nothing to reduce
    assert _claim(judged(), "Adapt below").holds
    spike = judged(cost=lambda m, k, r: 200.0 if (m, k) == ("adapt", 5) else {"explore": 100.0, "sysid": 95.0}.get(m, 80.0))
    assert _claim(spike, "Adapt below").holds is False and "13 of 14" in _claim(spike, "Adapt below").figure
    grows = judged(cost=lambda m, k, r: {"explore": 100.0, "sysid": 95.0}.get(m, 80.0 if k < 7 else 60.0))
    assert _claim(grows, "the gap").holds and _claim(judged(), "the gap").holds is False
    assert _claim(judged(rounds=7), "the gap").holds is None  # no new users' rounds (7-12), as the paper's Town4
    later = judged(cost=lambda m, k, r: {"explore": 100.0, "sysid": 95.0,
                                         "adapt_speed": 80.0 if k < 7 else 70.0}.get(m, 80.0))
    assert _claim(later, "Adapt-Speed like").holds and _claim(judged(), "Adapt-Speed like").holds is False
    closing = judged(cost=lambda m, k, r: {"explore": 100.0, "hindsight": 80.0 - 20.0 / (k + 2)}.get(m, 80.0))
    assert _claim(closing, "the regret").holds
    opening = judged(cost=lambda m, k, r: {"explore": 100.0, "hindsight": 80.0 - k}.get(m, 80.0))
    assert _claim(opening, "the regret").holds is False


def test_towns_not_run_are_reported_never_filled_in():
    page = paper_markdown(merge([compact(synthetic("Town3"))]))
    assert "Finished: Town3. Not yet run: Town1, Town2, Town4, Town5." in page
    assert page.count(": not yet run") == 4 and "### Town3\n" in page
    assert "| adapt | 1.85 (1.29) | not yet run |" in page  # Town1: the paper's figure only
    assert "Judged on Town3 (Town1, Town2, Town4, Town5 not yet run)." in page
    empty = paper_markdown(merge([]))
    assert all(c.holds is None for c in claims(merge([]))) and "fig3.png" not in empty
    assert "- **Adapt ≈ −50 % collisions vs explore**: not yet judged" in empty


def _page(tmp_path: Path) -> Path:
    page = tmp_path / "paper.md"
    page.write_text(f"# hand-written\n\nabove\n\n{BEGIN}\nold\n{END}\n\nbelow\n")
    return page


def test_compact_into_then_build_rebuilds_only_the_generated_section(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_text(json.dumps(synthetic()))
    results, page = tmp_path / "results", _page(tmp_path)
    assert main([str(run), "--compact-into", str(results), "--build", "--results", str(results), "--page", str(page),
                 "--figures", str(tmp_path / "paper")]) == 0
    merged = merge([json.loads((results / "Town2.json").read_text())])
    assert generated_section(page) == paper_markdown(merged)
    text = page.read_text()
    assert text.startswith("# hand-written\n\nabove\n\n") and text.endswith(f"{END}\n\nbelow\n")
    assert (tmp_path / "paper" / "fig3.png").stat().st_size > 1000 and (tmp_path / "paper" / "regret.png").exists()
    assert main(["--build", "--results", str(results), "--page", str(page), "--figures", str(tmp_path / "paper")]) == 0
    assert generated_section(page) == paper_markdown(merged)  # rebuilding changes nothing
    assert main([str(run), "--compact-into", str(results)]) == 0  # the same seed again: replaced


@pytest.mark.parametrize("case, words", [
    ("no results", "has no results.json"),
    ("not results", "is not a pernav study's results"),
    ("another seed", "with seed 0, this study has seed 1"),
    ("twice", "Town2 is given with seeds 0 and 1"),
    ("no markers", "needs one"),
    ("nothing", "nothing to do"),
    ("mixed presets", "different presets"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, case, words):
    def run_dir(name: str, results: dict) -> str:
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(results))
        return str(tmp_path / name)

    into, page = tmp_path / "results", _page(tmp_path)
    build = ["--build", "--results", str(into), "--page", str(page), "--figures", str(tmp_path / "paper")]
    if case == "no results":
        (tmp_path / "empty").mkdir()
        argv = [str(tmp_path / "empty"), "--compact-into", str(into)]
    elif case == "not results":
        argv = [run_dir("a", {"towns": []}), "--compact-into", str(into)]
    elif case == "another seed":
        assert main([run_dir("a", synthetic(seed=0)), "--compact-into", str(into)]) == 0
        argv = [run_dir("b", synthetic(seed=1)), "--compact-into", str(into)]
    elif case == "twice":
        argv = [run_dir("a", synthetic(seed=0)), run_dir("b", synthetic(seed=1)), "--compact-into", str(into)]
    elif case == "no markers":
        page.write_text("# no markers\n")
        argv = build
    elif case == "nothing":
        argv = []
    else:
        mixed = synthetic("Town3")
        mixed["config"]["preset"] = "smoke"
        assert main([run_dir("a", synthetic()), "--compact-into", str(into)]) == 0
        (into / "Town3.json").write_text(json.dumps(compact(mixed)))
        argv = build
    capsys.readouterr()
    before = page.read_text()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and words in err and err.count("\n") == 1, err
    assert page.read_text() == before


def test_merge_refuses_what_is_not_a_compact_town():
    with pytest.raises(PaperError, match="not a compact paper town"):
        merge([synthetic()])


@pytest.mark.slow
def test_the_committed_page_is_what_build_makes_of_the_committed_results(tmp_path):
    """docs/paper.md's generated section against ``--build`` on docs/paper/results/*.json (with no town committed
    yet, against the page that says so)."""
    page = tmp_path / "paper.md"
    shutil.copy(ROOT / "docs" / "paper.md", page)
    assert main(["--build", "--results", str(ROOT / "docs" / "paper" / "results"), "--page", str(page),
                 "--figures", str(tmp_path / "paper")]) == 0
    assert generated_section(ROOT / "docs" / "paper.md") == generated_section(page), (
        "docs/paper.md is stale: run `make paper` and commit it")


def test_add_into_gives_a_method_from_another_study_of_the_same_episodes_its_row_and_refuses_other_episodes(tmp_path,
                                                                                                           capsys):
    def run_dir(name: str, results: dict) -> str:
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(results))
        return str(tmp_path / name)

    into = tmp_path / "results"
    assert main([run_dir("table", synthetic()), "--compact-into", str(into)]) == 0
    more = synthetic(methods=("explore", "adapt_driver"), cost=lambda m, k, r: {"explore": 100.0}.get(m, 90.0) + r)
    more["regret"]["Town2"]["adapt_driver"] = {"labels": ["Online 0"], "loss_regret": [0.5]}
    file = into / "Town2.json"
    before = file.read_text()
    # another seed's or another explore's episodes: refused, the file untouched
    other_seed = synthetic(seed=1, methods=("explore", "adapt_driver"))
    other_explore = synthetic(methods=("explore", "adapt_driver"), cost=lambda m, k, r: 101.0 + r)
    for name, results, words in (("seed", other_seed, "seed 1"), ("explore", other_explore, "explore's episodes differ"),
                                 ("same", synthetic(), "adds no method")):
        capsys.readouterr()
        assert main([run_dir(name, results), "--add-into", str(into)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and words in err and err.count("\n") == 1, err
        assert file.read_text() == before
    assert main([run_dir("driver", more), "--add-into", str(into)]) == 0
    town = json.loads(file.read_text())
    table = town_table(town)
    assert set(table) == {*METHODS, "adapt_driver"}
    assert table["adapt_driver"]["explore_minus_method"]["mean"] == pytest.approx(10.0)  # paired with the file's explore
    assert table["adapt"] == town_table(json.loads(before))["adapt"]  # the other rows as they were
    assert town["regret"]["adapt_driver"]["loss_regret"] == [0.5] and "adapt_driver" in town["added"]
    assert "| adapt_driver |" in paper_markdown(merge([town]))
