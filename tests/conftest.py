import os
import sys
from pathlib import Path

import pytest
import torch

# the repository's root: the tests of recipes/ import them as ``recipes.benchmarks.*``, whatever the current folder;
# and the shared smoke study's helpers (tests/study/study_helpers.py), which the recipes' tests use too
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent / "study"))
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

# The longest checks, two by two, in the order they start under `make test` (pytest -n 2 --dist load
# --maxschedchunk 2 hands a worker the next two tests whenever it is down to its last one, so each pair runs on one
# worker, one test after the other). A pair shares what its tests build: the shared smoke study (Town1 and Town2 on
# a pool of two, tests/study/study_helpers.py) and the pool comparison (against the mini study), the recorded-drives
# study and its resume, the sweeps of tests/world/test_acceptance.py, the development drivers of
# tests/learners/test_belief.py (module fixtures, built again on every worker that runs one of their tests). The smoke
# study is built first, then the mini study (by the pool comparison, on the same worker); meanwhile the other worker
# runs the pairs that need neither (the recorded drives, the sweeps, the belief's development drivers), so that the
# checks that read the mini study (Ray, SIGKILL, a NaN loss) or the smoke study (the timing learner's) reach it once
# it is built and no worker waits on the other's study. Ids without parameters name every case of a parametrized test.
PAIRS = (
    ("tests/study/test_study.py::test_smoke_results_match_the_schema",
     "tests/study/test_study.py::test_a_towns_results_are_the_same_in_one_process_and_in_a_pool_of_two_workers"),
    ("tests/study/test_recorded_schedule.py::test_a_study_learns_from_recorded_and_simulated_drives",
     "tests/study/test_recorded_schedule.py::test_a_study_with_recorded_drives_killed_after_a_person_resumes_to_the_"
     "same_results"),
    ("tests/world/test_acceptance.py::test_best_lead_time_is_personal",
     "tests/world/test_acceptance.py::test_too_late_misses_and_too_early_goes_wrong"),
    ("tests/learners/test_belief.py::test_a_late_answering_driver_gets_a_later_belief_and_earlier_prompts_a_quick_one_"
     "explore",
     "tests/learners/test_belief.py::test_the_posterior_narrows_with_drives_of_the_same_driver"),
    ("tests/study/test_reliability.py::test_smoke_study_on_local_ray_equals_single_process",
     "tests/study/test_reliability.py::test_sigkill_at_random_moments_then_resume_gives_the_same_results"),
    ("tests/study/test_headroom.py::test_a_study_runs_the_timing_learner_and_records_its_beliefs",
     "tests/study/test_reliability.py::test_nan_loss_is_skipped_and_the_study_finishes"),
    # the belief's development drivers are built by the pair before; started beside it, this pair waited for them
    ("tests/learners/test_belief.py::test_within_a_drive_the_belief_moves_after_an_answered_prompt_and_the_prompts_"
     "follow",
     "tests/learners/test_belief.py::test_a_late_deciding_driver_gets_a_later_decision_time_from_its_junctions_outcomes"),
    ("tests/world/test_acceptance.py::test_too_late_swerves_strike_for_truck_and_fast_keyboard",
     "tests/play/test_play.py::test_bench_play_reports_frame_times"),
)

# Slow tests that read what another slow test of their module builds for both workers (a shared folder): they go after
# the other slow tests, so that it is built by then (started beside its builder, a worker waited for it, 19 s)
LATE = ("tests/play/test_lab_study.py",)
BUILDERS = ("tests/play/test_lab_study.py::test_three_participants_drive_the_learners_as_counterbalanced_conditions",)


def pytest_collection_modifyitems(config, items):
    """The tests of :data:`PAIRS` first, in that order, then the other tests marked ``slow``, then the rest, so
    that under ``pytest -n 2 --dist load --maxschedchunk 2`` (``make test``) the long checks start early on both
    workers and the short ones fill in around them, instead of a long check starting last while the other worker
    idles. The other slow tests of the folders whose checks take longest come first, a module at a time from each
    folder in turn: a module's tests stay together, so that its module fixtures are built once per worker instead
    of again each time the order comes back to it. The tests of :data:`LATE` but their builders go after the other slow
    tests."""
    order = ("study", "world", "play")
    first = [nodeid for pair in PAIRS for nodeid in pair]

    def folder(item) -> int:
        parts = item.path.relative_to(config.rootpath).parts  # ("tests", "study", "test_x.py"), ("pernav", ...)
        name = parts[1] if parts[0] == "tests" and len(parts) > 2 else ""
        return order.index(name) if name in order else len(order)

    def rank(item) -> int:
        for nodeid in (item.nodeid, item.nodeid.split("[")[0]):
            if nodeid in first:
                return first.index(nodeid)
        return len(first)

    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    modules: list[list[list]] = [[] for _ in range(len(order) + 1)]  # per folder, its modules' slow tests
    for item in slow:
        in_folder = modules[folder(item)]
        if not in_folder or in_folder[-1][0].path != item.path:
            in_folder.append([])
        in_folder[-1].append(item)
    turns = [item for i in range(max(map(len, modules), default=0)) for in_folder in modules if i < len(in_folder)
             for item in in_folder[i]]
    turns.sort(key=rank)  # stable: the slow tests not in PAIRS keep their turns

    def late(item) -> bool:
        return item.nodeid.split("::")[0] in LATE and item.nodeid not in BUILDERS

    turns = [item for item in turns if not late(item)] + [item for item in turns if late(item)]
    items[:] = turns + [item for item in items if item.get_closest_marker("slow") is None]


@pytest.fixture(autouse=True)
def _seeded_global_generator():
    """Every test starts from the same global torch generator: under pytest-xdist which tests ran before one on its
    worker varies from run to run, and a model built from the global generator would vary with it (a check that FTML
    lowers its loss once failed that way)."""
    torch.manual_seed(0)
