"""A town's checkpoints: the run's state round-trips, and a checkpoint written before :class:`RunState` resumes."""

from __future__ import annotations

from typing import Any

import pytest

from pernav.study.checkpoints import RunState, final_belief, load_checkpoint, save_checkpoint
from pernav.study.errors import CheckpointError


class _PlainDictState:
    """The state as the runner saved it before :class:`RunState`: a plain dict, the rounds' wall time as ``timing``,
    and only the keys that had been set."""

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data

    def to_dict(self) -> dict[str, Any]:
        return self.data


def test_the_run_state_round_trips_through_a_checkpoint(tmp_path):
    state = RunState(next=2, results=[{"label": "Offline 0", "phase": "offline", "methods": {}}],
                     online_losses={"Online 0": 1.5}, wall_time={"Offline 0": 3.2}, profile={"training_s": 1.0},
                     belief_model={"detector": {}, "prior": {"mean": 1.0}})
    save_checkpoint(tmp_path, 1, state, {})
    assert load_checkpoint(tmp_path, {}) == state


def test_a_checkpoint_from_before_the_typed_state_resumes(tmp_path):
    old = {"next": 3, "results": [{"label": "Online 0", "phase": "online", "methods": {}}], "warm": {"adapt": {}},
           "online_losses": {"Online 0": 2.0}, "unadapted_losses": {"Online 0": 2.5}, "timing": {"Online 0": 9.5},
           "profile": {"evaluation_s": 4.0}, "hindsight": {"evaluations": {}, "losses": {"Online 0": 1.9}}}
    save_checkpoint(tmp_path, 2, _PlainDictState(old), {})
    state = load_checkpoint(tmp_path, {})
    assert state.next == 3 and state.wall_time == {"Online 0": 9.5} and state.hindsight == old["hindsight"]
    assert state.fixed_step_losses == {} and state.timing_beliefs == {} and state.belief_model is None  # never set


def test_final_belief_reads_the_state_and_names_a_study_without_it(tmp_path):
    town = tmp_path / "checkpoints" / "Town1"
    save_checkpoint(town, 0, RunState(belief_model={"detector": {"w": 1}, "prior": {}}), {})
    assert final_belief(tmp_path, "Town1") == {"detector": {"w": 1}, "prior": {}}
    save_checkpoint(town, 1, _PlainDictState({"next": 1, "results": []}), {})  # an older study without belief
    with pytest.raises(CheckpointError, match="did not run the belief learner"):
        final_belief(tmp_path, "Town1")
