"""Was a "turn" prompt in time (pernav.learners.outcomes), and the decision time's posterior it feeds
(ReactionBelief.update_turn): outcomes read from synthetic drives whose junctions, misses and swerves are known, the
swerve detector on separable data, and the posterior's arithmetic against brute force."""

import math

import pytest
import torch

from pernav.env.policies import belief_policy, explore_policy
from pernav.learners.belief import SIGMA, DecisionPrior, ReactionBelief
from pernav.learners.outcomes import STEP_FEATURES, SwerveDetector, commit_room, step_summaries, turn_outcomes

TURN, PREPARE = 1, 3  # turn left, prepare left (pernav.world.constants.Instruction)


def _drive(T: int = 14, junction_at: int = 6):
    """A drive at 10 m/s that passes a junction in step ``junction_at`` (its distance jumps back up there)."""
    frames = torch.zeros(T, 10, 5)
    frames[..., 0] = 10.0
    distance = torch.tensor([10.0 * (junction_at - t) for t in range(junction_at)]
                            + [300.0 - 10 * t for t in range(T - junction_at)])
    return torch.arange(1.0, T + 1), distance, frames


def test_an_announced_junction_gives_its_slack_and_no_lateness_when_nothing_happened():
    times, distance, frames = _drive()
    outcomes = turn_outcomes([(PREPARE, 0.5), (TURN, 2.5), (TURN, 4.5)], times, distance, torch.zeros(14),
                             torch.zeros(14), frames)
    assert len(outcomes) == 1  # one junction, judged on its first "turn" prompt; a "prepare" is not judged
    (o,) = outcomes
    assert o.end == 2.5 and not o.late and o.step == 6
    assert o.slack == pytest.approx(7.0 - 2.5)  # step 5 ended at 6 s, 10 m before the junction at 10 m/s
    at_two = ReactionBelief.D_GRID.tolist().index(2.0)
    assert float(o.room[at_two]) == pytest.approx(7.0 - 2.0 - 2.5, abs=0.11)  # commits 20 m out, 2 s before arrival


def test_a_miss_or_a_swerve_after_the_prompt_makes_it_late_one_before_it_does_not():
    times, distance, frames = _drive()
    missed = torch.zeros(14)
    missed[7:] = 1  # the navigation counted a missed turn just after the junction
    assert turn_outcomes([(TURN, 2.5)], times, distance, missed, torch.zeros(14), frames)[0].late
    swerve = torch.zeros(14)
    swerve[5] = 0.9
    assert turn_outcomes([(TURN, 2.5)], times, distance, torch.zeros(14), swerve, frames)[0].late
    before = torch.ones(14)  # a miss counted before the prompt belongs to an earlier junction
    assert not turn_outcomes([(TURN, 2.5)], times, distance, before, torch.zeros(14), frames)[0].late


def test_a_drive_in_progress_waits_until_the_outcome_can_show():
    times, distance, frames = _drive(T=8)
    assert turn_outcomes([(TURN, 2.5)], times, distance, torch.zeros(8), torch.zeros(8), frames, complete=True) == []
    assert len(turn_outcomes([(TURN, 2.5)], times, distance, torch.zeros(8), torch.zeros(8), frames)) == 1


def test_the_swerve_detector_learns_a_hard_brake_with_a_steering_jerk():
    g = torch.Generator().manual_seed(0)
    drives = []
    for k in range(6):
        frames = torch.zeros(30, 10, 5)
        frames[..., 0] = 8.0 + torch.rand(30, 1, generator=g)
        frames[..., 2] = 0.3 * torch.rand(30, 10, generator=g)
        began = torch.zeros(30)
        at = 5 + 4 * k
        frames[at:at + 3, :, 2] = 0.9  # harsh braking for 3 s
        frames[at, 5:, 3] = 0.8  # and a sharp steer
        began[at] = 1
        drives.append((frames, began))
    detector = SwerveDetector().fit(drives[:4])
    for frames, began in drives[4:]:
        p = detector(frames)
        assert p.shape == (30,) and int(p.argmax()) == int(began.argmax())
        assert p[began.bool()].item() > 0.5 > p[~began.bool()].max().item()
    assert step_summaries(drives[0][0]).shape == (30, STEP_FEATURES)


PRIOR = DecisionPrior(mean=2.0, sd=0.6, hit=0.6, false=0.02)


def _room(slack: float, approach: float = 10.0) -> torch.Tensor:
    """The room of a prompt ``slack`` s before the junction at a steady ``approach`` speed (m/s)."""
    return torch.tensor([slack - max(D, 4.0 / approach) for D in ReactionBelief.D_GRID.tolist()], dtype=torch.float64)


def test_the_room_before_the_commit_follows_the_cars_speed_on_its_approach():
    times = torch.arange(0.1, 10.05, 0.1)
    steady = commit_room(times, torch.full((len(times),), 10.0), arrival=10.0, end=4.0)
    assert steady[ReactionBelief.D_GRID.tolist().index(2.0)] == pytest.approx(10.0 - 2.0 - 4.0, abs=0.11)
    slowing = commit_room(times, torch.linspace(14.0, 5.0, len(times)), arrival=10.0, end=4.0)
    assert (slowing <= steady + 1e-9).all()  # a car slowing on its approach commits earlier, farther out
    assert (steady.diff() <= 0).all()  # a later decision time leaves less room


def test_update_turn_is_the_grid_posterior_of_the_brute_force_likelihood():
    belief = ReactionBelief(math.log(1.2), 0.3, decision=PRIOR)
    outcomes = [(4.0, True), (6.0, False), (3.5, True)]
    for slack, late in outcomes:
        belief.update_turn(_room(slack), late)
    R, D = ReactionBelief.GRID[:, None], ReactionBelief.D_GRID[None]
    log_p = -0.5 * ((R - math.log(1.2)) / 0.3) ** 2 - 0.5 * ((D - 2.0) / 0.6) ** 2
    for slack, late in outcomes:
        room = _room(slack)
        for i in range(len(ReactionBelief.GRID)):
            for j in range(len(ReactionBelief.D_GRID)):
                mu = float(R[i, 0]) - SIGMA**2 / 2
                r = float(room[j])
                p_late = 1.0 if r <= 0 else 0.5 * math.erfc((math.log(r) - mu) / (SIGMA * math.sqrt(2)))
                p = 0.02 + (0.6 - 0.02) * p_late
                log_p[i, j] += math.log(p if late else 1 - p)
    w = torch.exp(log_p - log_p.max())
    w = w / w.sum()
    assert belief.decision_mean == pytest.approx(float((w.sum(0) * ReactionBelief.D_GRID).sum()), abs=1e-9)
    assert belief.mean == pytest.approx(float((w.sum(1) * ReactionBelief.GRID).sum()), abs=1e-9)


def test_late_turns_raise_the_decision_time_and_move_the_prompts_earlier_in_time_ones_never_later():
    late, timely = (ReactionBelief(math.log(1.2), 0.3, decision=PRIOR) for _ in range(2))
    for _ in range(4):
        late.update_turn(_room(5.0), True)  # a swerve or a miss although the prompt ended 5 s before the junction
        timely.update_turn(_room(5.0), False)
    assert late.decision_mean > PRIOR.mean + 0.3 and timely.decision_mean < PRIOR.mean
    acted = late.belief()
    assert acted["decision_time"] > explore_policy().driver.decision_time
    assert belief_policy(acted).turn_lead(10.0) > belief_policy({k: v for k, v in acted.items()
                                                                 if k != "decision_time"}).turn_lead(10.0)
    assert "decision_time" not in timely.belief()
    low, high = late.decision_interval(0.9)
    assert low < late.decision_mean < high


def test_without_a_decision_prior_turn_outcomes_are_ignored_and_old_states_load():
    belief = ReactionBelief(0.2, 0.4)
    before = belief.log_post.clone()
    belief.update_turn(_room(3.0), True)
    assert torch.equal(belief.log_post, before) and belief.outcomes == 0
    with pytest.raises(ValueError, match="decision"):
        belief.decision_weights()
    state = belief.state_dict()
    del state["outcomes"], state["decision"]  # a posterior saved before the decision time existed
    assert ReactionBelief.from_state_dict(state).mean == belief.mean


def test_a_joint_belief_survives_its_state_dict():
    belief = ReactionBelief(0.2, 0.4, decision=PRIOR)
    belief.update_turn(_room(4.0), True)
    again = ReactionBelief.from_state_dict(belief.state_dict())
    assert again.decision == PRIOR and again.outcomes == 1
    assert again.decision_mean == belief.decision_mean and again.belief() == belief.belief()
