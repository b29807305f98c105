"""A finished study opened once (:class:`pernav.study.finished.FinishedStudy`) hands out every learner's policy as
the play sessions built it before the study could be opened as one object: the same adapted parameters, planner, env
settings and drives for a dynamics model's learner; the same belief for the learners that re-time explore's rule. On
the small studies of the play tests (tests/play/play_helpers.py, built once per test session)."""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import fields
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "play"))  # the play tests' small finished studies
from play_helpers import PLANNER, K, model_study, retimed_study  # noqa: E402

from pernav.env.torchrl_env import info_action_module  # noqa: E402
from pernav.learners.belief import BeliefTracker  # noqa: E402
from pernav.learners.timing import TimingModel  # noqa: E402
from pernav.model.dynamics import DynamicsModel  # noqa: E402
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model  # noqa: E402
from pernav.planner.factory import build_planner, env_planning_config  # noqa: E402
from pernav.play.loop import PlaySession
from pernav.play.options import PlayError, PlayOptions
from pernav.play.personal import study_history, study_policy  # noqa: E402
from pernav.study.checkpoints import final_belief, final_models  # noqa: E402
from pernav.study.config import BELIEF_DEFAULTS, LEARNERS  # noqa: E402
from pernav.study.finished import (  # noqa: E402
    TRAIN_ADDED,
    FinishedStudy,
    RetimedPolicy,
    StudyError,
    StudyPolicy,
    adapted_parameters,
)
from pernav.trainer.collect import in_action_space  # noqa: E402
from pernav.trainer.ensemble import EnsembleTrainer  # noqa: E402
from pernav.trainer.ftml import TrainConfig  # noqa: E402
from pernav.world.constants import N_ADAPTIVE_ACTIONS  # noqa: E402

# every test here opens a finished study, built on first use (about 35 s): not for `make test-fast`
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    return model_study(tmp_path_factory)


@pytest.fixture(scope="module")
def retimed(tmp_path_factory) -> Path:
    return retimed_study(tmp_path_factory)


@pytest.fixture(scope="module")
def tau() -> object:
    """A person's explore drive of Town1 recorded with the model study's history window."""
    return PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, K=K)).run(max_steps=30).trajectory


@pytest.fixture(scope="module")
def whole_tau() -> object:
    """A slow driver's whole explore drive of Town1 (its answers, and timing features that move the prompts)."""
    return PlaySession("Town1", 0, user="user3", options=PlayOptions(n_traffic=0)).run().trajectory


def _reference(study_dir: Path, town: str, learner: str, drives: list, seed: int) -> dict:
    """What ``pernav.play.personal.study_policy`` built from the checkpoint's parts before the study could be opened
    as one object: the settings, the trainer from the final members, the parameters adapted on the drives, the
    planner and the env settings it planned on."""
    config = json.loads((study_dir / "study.json").read_text())
    known = {f.name for f in fields(TrainConfig)}
    train = TrainConfig(**{**TRAIN_ADDED, **{k: v for k, v in config["train"].items() if k in known}})
    model, members = final_models(study_dir, town, learner)
    planner = dict(config.get("planner") or {"kind": "retime"})
    n_actions = LEARNERS[learner]
    trainer = EnsembleTrainer.from_states(model.config(), members, train, None, seed)
    if drives and learner != "sysid":
        drives = [in_action_space(d, n_actions) for d in drives]
        params = trainer.adapted_parameters(drives[-1], drives, seed=seed)
    else:
        params = trainer.adapted_parameters(None, meta=False)
    net = DynamicsModel(**model.config())
    net.load_state_dict(members[0])
    module = build_planner(ImaginedNavigationEnv(make_world_model(net)), planner, n_actions)
    module.params = params
    return {"planner": module, "params": params, "members": len(members), "train": train,
            "env_config": {"adaptive_speed": n_actions == N_ADAPTIVE_ACTIONS, **env_planning_config(planner)},
            "K": int(model.config()["K"])}


def _same_params(a: list, b: list) -> bool:
    return len(a) == len(b) and all(torch.equal(x[k], y[k]) for x, y in zip(a, b, strict=True)
                                    for k in x.keys(True, True))


def _same_state(a: object, b: object) -> bool:
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same_state(a[k], b[k]) for k in a)
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    return a == b


def _actions(policy, route: int = 2, steps: int = 5, **options) -> torch.Tensor:
    return PlaySession("Town1", route, policy=policy, options=PlayOptions(n_traffic=0, **options)).run(
        max_steps=steps).trajectory["action"]


@pytest.mark.parametrize("learner,adapted", [("adapt", True), ("adapt", False), ("adapt_speed", True)])
def test_a_model_learners_policy_is_the_one_the_play_sessions_built(models, tau, learner, adapted):
    drives = [tau] if adapted else []
    policy, info = FinishedStudy.open(models).policy(learner, "Town1", tau if adapted else None, seed=3)
    ref = _reference(models, "Town1", learner, drives, seed=3)
    assert isinstance(policy, StudyPolicy) and policy.__name__ == "study"
    assert _same_params(policy.planner.params, ref["params"])
    assert policy.env_config == ref["env_config"] and policy.K == ref["K"] == K
    assert policy.n_actions == LEARNERS[learner] and (policy.planner.horizon, policy.planner.advance) == (8, 4)
    assert info == {"study": str(models), "town": "Town1", "learner": learner, "members": ref["members"],
                    "adapted": adapted, "adaptation": "U" if adapted else None,
                    "tau_steps": [int(tau.shape[0])] if adapted else [], "planner": {"kind": "retime", **PLANNER},
                    "env_config": ref["env_config"], "K": K}
    # the same prompts on the same drive: the policy plans as the reference planner does
    assert torch.equal(_actions(policy), _actions(ref["planner"], K=ref["K"], env_config=ref["env_config"]))


def test_study_policy_is_the_studys_policy_in_plays_words(models, tau):
    policy, info = study_policy(models, "Town1", tau, learner="adapt", seed=1)
    theirs, their_info = FinishedStudy.open(models).policy("adapt", "Town1", [tau], seed=1)
    assert info == their_info and _same_params(policy.planner.params, theirs.planner.params)
    assert study_history(models, "Town1") == K == FinishedStudy.open(models).history("Town1")
    with pytest.raises(PlayError, match="history of 5 steps: the study's model reads 3"):
        study_policy(models, "Town1", PlaySession("Town1", 0, options=PlayOptions(n_traffic=0)).run(3).trajectory)
    with pytest.raises(PlayError, match="did not run Town2; it ran Town1"):
        study_history(models, "Town2")


def test_adapted_parameters_refuse_a_drive_of_another_history(models, tau):
    study = FinishedStudy.open(models).model("Town1")
    five = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, K=5)).run(max_steps=3).trajectory
    with pytest.raises(StudyError, match=f"history of 5 steps: the study's model reads {K}"):
        adapted_parameters(study, study.trainer(), [five])
    assert len(adapted_parameters(study, study.trainer(), [tau])) == study.train.ensemble


def test_the_study_is_read_once_and_says_what_it_ran(models, retimed):
    study = FinishedStudy.open(models)
    assert study.folder == models and study.towns == ["Town1"] and study.model_learners == ["adapt", "adapt_speed"]
    assert study.planner == PLANNER and study.train.K == K == study.model("Town1").K
    assert FinishedStudy.open(retimed).model_learners == [] and "belief" in FinishedStudy.open(retimed).methods
    with pytest.raises(StudyError, match="learner 'sysid' not in the study; it trained adapt, adapt_speed"):
        study.model("Town1", "sysid")
    with pytest.raises(StudyError, match="learner 'adapt' not in the study; it trained none"):
        FinishedStudy.open(retimed).policy("adapt", "Town1")
    with pytest.raises(StudyError, match="did not run the belief learner"):
        study.policy("belief", "Town1")
    with pytest.raises(StudyError, match="did not run the timing learner"):
        study.policy("timing", "Town1")


def test_train_options_added_later_take_the_values_older_studies_ran_with(models, tmp_path):
    assert TRAIN_ADDED == {"ensemble": 1, "personal_updates": 0, "personal_replay": 0.0, "road": 0, "context": 0}
    older = tmp_path / "older"
    shutil.copytree(models, older)
    config = json.loads((older / "study.json").read_text())
    config["train"] = {k: v for k, v in config["train"].items() if k not in TRAIN_ADDED}
    (older / "study.json").write_text(json.dumps(config))
    train = FinishedStudy.open(older).train
    assert (train.ensemble, train.personal_updates, train.personal_replay, train.road, train.context) == (1, 0, 0.0, 0, 0)


def test_the_belief_policy_is_the_studys_tracker_as_the_belief_session_had_it(retimed, whole_tau):
    study = FinishedStudy.open(retimed)
    policy, info = study.policy("belief", "Town1")
    guard = bool({**BELIEF_DEFAULTS, **json.loads((retimed / "study.json").read_text())["belief"]}["guard"])
    reference = BeliefTracker.from_model(final_belief(retimed, "Town1"), guard=guard)
    assert isinstance(policy, RetimedPolicy) and policy.__name__ == "belief"
    assert policy.env_config == {"belief": policy.belief} and not info["adapted"]
    assert policy.belief.fields() == reference.fields() == info["belief"]
    # the same drive as with the env's belief_action and the reference tracker (BeliefSession's way before)
    assert torch.equal(_actions(policy, route=1, steps=8),
                       _actions(info_action_module("belief_action"), route=1, steps=8, env_config={"belief": reference}))
    # adapted on tau: the tracker has read tau's answers
    adapted, adapted_info = study.policy("belief", "Town1", whole_tau)
    reference.observe_drive(whole_tau)
    assert adapted_info["adapted"] and _same_state(adapted.belief.belief.state_dict(), reference.belief.state_dict())
    assert adapted.belief.fields() == reference.fields() and adapted.belief.belief.answers == reference.belief.answers > 0


def test_the_timing_policy_reads_tau_as_the_study_does(retimed, whole_tau):
    manifest = json.loads((retimed / "checkpoints" / "Town1" / "manifest.json").read_text())
    state = torch.load(retimed / "checkpoints" / "Town1" / manifest["folder"] / "state.pt", weights_only=False)
    expected = TimingModel().load_state_dict(state["state"]["timing_model"]).belief(whole_tau)  # the runner's rule
    policy, info = FinishedStudy.open(retimed).policy("timing", "Town1", whole_tau)
    assert isinstance(policy, RetimedPolicy) and policy.__name__ == "timing"
    assert policy.env_config == {"belief": expected} and info["belief"] == expected and info["adapted"]
    assert expected["reaction_time"] > 0  # the slow driver's prompts move (else the study leaves explore's timing)
    unadapted, info0 = FinishedStudy.open(retimed).policy("timing", "Town1")
    assert unadapted.env_config == {"belief": {}} and not info0["adapted"]  # explore's timing
    assert torch.equal(_actions(unadapted, route=1), _actions("explore", route=1))


def test_a_folder_without_a_finished_study_is_refused_by_name(models, tmp_path):
    with pytest.raises(StudyError, match="no study folder"):
        FinishedStudy.open(tmp_path / "none")
    (tmp_path / "empty").mkdir()
    with pytest.raises(StudyError, match=r"holds no pernav study \(no study.json\)"):
        FinishedStudy.open(tmp_path / "empty")
    unfinished = tmp_path / "unfinished"
    shutil.copytree(models, unfinished)
    (unfinished / "results.json").unlink()
    with pytest.raises(StudyError, match="is not finished"):
        FinishedStudy.open(unfinished)
    (unfinished / "study.json").write_text("[1, 2]")
    with pytest.raises(StudyError, match="is not a study configuration"):
        FinishedStudy.open(unfinished)
    broken = tmp_path / "broken"
    shutil.copytree(models, broken)
    for state in (broken / "checkpoints" / "Town1").glob("entry_*/state.pt"):
        state.write_bytes(b"cut short")
    with pytest.raises(StudyError, match="cannot read the study's Town1 checkpoint: .*corrupted"):
        FinishedStudy.open(broken).policy("adapt", "Town1")
