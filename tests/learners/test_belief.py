"""The belief about a driver from each prompt's answer (pernav.learners.belief): the posterior's arithmetic on answers
whose moment is known, and the whole chain (frames -> detector -> posterior -> prompts) on simulated drives."""

import math

import pytest
import torch
from navigation_helpers import shared_value

from pernav.env.navigation import NavigationEnv
from pernav.env.policies import belief_policy, explore_policy
from pernav.env.torchrl_env import explore_module
from pernav.learners.answers import fit_belief, labelled_drives
from pernav.learners.belief import DT, SIGMA, BeliefTracker, ReactionBelief
from pernav.trainer.collect import drive, history_env
from pernav.world.constants import TURNS
from pernav.world.drivers import Context, DriverProfile


def _answer(delay: float, sharp: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Candidate frames 0.3-9 s after the audio, the detector's weight ``sharp`` on the frame at ``delay``."""
    delays = torch.arange(0.3, 9.0, DT)
    probs = torch.zeros(len(delays))
    probs[int(torch.argmin((delays - delay).abs()))] = sharp
    return delays, probs


def _draws(R: float, n: int, seed: int) -> list[float]:
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(n, generator=g, dtype=torch.float64)
    return (math.log(R) - SIGMA**2 / 2 + SIGMA * z).exp().tolist()


@pytest.mark.parametrize("R", [0.7, 1.2, 2.4])
def test_answers_drawn_from_a_driver_give_a_posterior_around_its_reaction_time(R):
    belief = ReactionBelief(prior_mean=math.log(1.4), prior_sd=0.4)
    for delay in _draws(R, 30, seed=int(R * 10)):
        belief.update(*_answer(delay), none=0.0)
    low, high = belief.interval(0.99)
    assert low < R < high
    assert abs(belief.mean - math.log(R)) < 0.15


def test_the_posterior_narrows_as_answers_accumulate_and_no_answer_says_little_unless_its_window_was_short():
    belief = ReactionBelief(prior_mean=math.log(1.4), prior_sd=0.4)
    sds = [belief.sd]
    for delay in _draws(1.8, 20, seed=3):
        belief.update(*_answer(delay), none=0.0)
        sds.append(belief.sd)
    assert sds[5] < sds[0] and sds[20] < sds[5]
    before = belief.mean
    delays, _ = _answer(1.0)
    belief.update(delays, torch.zeros(len(delays)), none=1.0)  # nothing visible in 9 s: almost no evidence about R
    assert abs(belief.mean - before) < 0.005
    short = delays[delays < 1.5]  # the next prompt cut the window at 1.5 s: an answer after it is likelier if slow
    for _ in range(3):
        belief.update(short, torch.zeros(len(short)), none=1.0)
    assert belief.mean > before + 0.01


def test_a_slow_belief_times_prompts_earlier_and_a_quick_one_keeps_explore():
    slow, quick = (ReactionBelief(prior_mean=math.log(1.4), prior_sd=0.4) for _ in range(2))
    for delay in _draws(2.5, 12, seed=1):
        slow.update(*_answer(delay), none=0.0)
    for delay in _draws(0.7, 12, seed=2):
        quick.update(*_answer(delay), none=0.0)
    assert quick.belief() == {}  # explore's own timing
    acted = slow.belief()
    assert acted["reaction_time"] > 2.0 and acted["fastest"]["reaction_time"] < acted["reaction_time"]
    assert belief_policy(acted).turn_lead(10.0) > explore_policy().turn_lead(10.0) + 5.0


def test_a_drivers_own_reading_error_keeps_the_posterior_from_narrowing_below_it():
    plain, drifting = ReactionBelief(math.log(1.4), 0.4), ReactionBelief(math.log(1.4), 0.4, drift=0.1)
    for delay in _draws(1.8, 60, seed=5):
        plain.update(*_answer(delay), none=0.0)
        drifting.update(*_answer(delay), none=0.0)
    assert plain.sd < 0.06 < 0.09 < drifting.sd < 0.13  # sqrt(plain^2 + 0.1^2), give or take the prior's pull
    assert abs(drifting.mean - plain.mean) < 0.03
    low, high = drifting.interval(0.9)
    assert low < plain.interval(0.9)[0] < plain.interval(0.9)[1] < high
    again = ReactionBelief.from_state_dict(drifting.state_dict())
    assert again.drift == 0.1 and again.sd == drifting.sd


def test_a_wide_belief_on_the_quick_side_of_the_average_driver_keeps_explore_with_slower():
    average = explore_policy().driver.reaction_time
    for shift, acts in ((-0.15, False), (0.15, True)):  # posterior median below / above the average driver's
        wide = {"prior_mean": math.log(average) + shift, "prior_sd": 0.4}
        plain, gated = ReactionBelief(**wide), ReactionBelief(**wide, slower=0.5)
        # P(R > average) of a normal log R against its grid sum
        expected = 0.5 * math.erfc(-shift / 0.4 / math.sqrt(2))
        assert gated.slower_than(average) == pytest.approx(expected, abs=0.01)
        assert "reaction_time" in plain.belief()  # its upper value (mean + 1 SD) is later than the average's
        assert ("reaction_time" in gated.belief()) is acts
    again = ReactionBelief.from_state_dict(gated.state_dict())
    assert again.slower == 0.5 and again.belief() == gated.belief()


def test_a_belief_survives_its_state_dict():
    belief = ReactionBelief(prior_mean=0.2, prior_sd=0.4, noise=0.2, outlier=0.3, quantile=1.5)
    belief.update(*_answer(2.0), none=0.1)
    again = ReactionBelief.from_state_dict(belief.state_dict())
    assert again.mean == belief.mean and again.answers == 1 and again.quantile == 1.5


# ----- the chain on simulated drives --------------------------------------------------------------------------
SLOW = (DriverProfile(reaction_time=2.4, decision_time=2.0), Context(visual="foggy"))
QUICK = (DriverProfile(reaction_time=0.6, decision_time=1.5), Context())


@pytest.fixture(scope="module")
def offline(tmp_path_factory):
    """24 simulated development drivers of Town1 (population seed 9201), one explore drive each (built once for
    both pytest workers)."""
    return shared_value(tmp_path_factory, "belief_development_drives", lambda: labelled_drives(
        "Town1", n=24, population_seed=9201, seed=0, config={"n_traffic": 2}))


@pytest.fixture(scope="module")
def fitted(offline):
    """A detector and prior fitted on the development drivers."""
    return fit_belief(offline)


@pytest.fixture(scope="module")
def fitted_decision(offline):
    """The same with the decision time: the swerve detector and the decision time's likelihood too."""
    return fit_belief(offline, decision=True)


def _tau(driver, route: int, seed: int):
    profile, context = driver
    env = history_env("Town1", {"route": route, "user": profile, "context": context}, config={"n_traffic": 2},
                      seed=seed)
    return drive(env, explore_module())


def _read(fitted, taus) -> BeliefTracker:
    detector, prior, swerve = fitted
    tracker = BeliefTracker(detector, ReactionBelief.from_state_dict(prior.state_dict()), swerve=swerve)
    for tau in taus:
        tracker.observe_drive(tau)
    return tracker


@pytest.mark.slow
def test_a_late_answering_driver_gets_a_later_belief_and_earlier_prompts_a_quick_one_explore(fitted):
    slow, quick = _read(fitted, [_tau(SLOW, 1, 3)]), _read(fitted, [_tau(QUICK, 1, 3)])
    assert slow.belief.mean_reaction() > quick.belief.mean_reaction() + 0.8
    assert slow.belief.interval()[0] > 1.4  # the slow driver's 90 % interval lies above the average's 1.2 s
    assert belief_policy(slow.fields()).turn_lead(10.0) > explore_policy().turn_lead(10.0) + 5.0
    assert quick.fields() == {}  # explore's own timing


@pytest.mark.slow
def test_the_posterior_narrows_with_drives_of_the_same_driver(fitted):
    taus = [_tau(SLOW, route, seed) for route, seed in ((1, 3), (2, 4), (4, 5))]
    one, three = _read(fitted, taus[:1]), _read(fitted, taus)
    assert three.belief.sd < one.belief.sd
    assert three.belief.answers > one.belief.answers


@pytest.mark.slow
def test_within_a_drive_the_belief_moves_after_an_answered_prompt_and_the_prompts_follow(fitted):
    detector, prior, _ = fitted
    tracker = BeliefTracker(detector, ReactionBelief.from_state_dict(prior.state_dict()))
    env = NavigationEnv("Town1", config={"n_traffic": 2, "belief": tracker})
    _, info = env.reset(seed=3, options={"route": 1, "user": SLOW[0], "context": SLOW[1]})
    assert env.tracker is not tracker  # the drive's own copy: the caller's belief is left as it was
    at_start, done, moved_at = info["belief_reaction"], False, None
    while not done:
        _, _, terminated, truncated, info = env.step(info["belief_action"])
        done = terminated or truncated
        if moved_at is None and env.tracker.belief.answers:
            moved_at = env.time
            assert env.tracker.belief.mean != tracker.belief.mean  # one answer read: the belief moved
    assert moved_at is not None and moved_at < env.time  # read during the drive, not after it
    assert info["belief_reaction"] > at_start  # the slow driver's prompts are timed for a slower driver now
    assert tracker.belief.answers == 0


LATE_DECIDER = (DriverProfile(reaction_time=1.6, decision_time=3.0), Context(vehicle="cybertruck"))  # D 3.8 s
EARLY_DECIDER = (DriverProfile(reaction_time=1.6, decision_time=1.0), Context())


@pytest.mark.slow
def test_a_late_deciding_driver_gets_a_later_decision_time_from_its_junctions_outcomes(fitted_decision):
    _, prior, swerve = fitted_decision
    assert swerve is not None and 0.0 <= prior.decision.false < prior.decision.hit <= 1.0
    drives = ((1, 3), (2, 4), (4, 5))
    late = _read(fitted_decision, [_tau(LATE_DECIDER, r, s) for r, s in drives])
    early = _read(fitted_decision, [_tau(EARLY_DECIDER, r, s) for r, s in drives])
    assert late.belief.outcomes > 0 and early.belief.outcomes > 0
    assert late.belief.decision_mean > early.belief.decision_mean + 0.3
    assert late.fields().get("decision_time", 0.0) > early.fields().get("decision_time", 0.0)


def test_a_labelled_drive_plays_the_given_policy_s_prompts_and_labels_them():
    from pernav.learners.answers import labelled_drive

    def turns(policy) -> list[float]:
        d = labelled_drive("Town1", DriverProfile(reaction_time=1.0), Context(), 1, 5, {"n_traffic": 0}, policy)
        return [s["time"] for s in d.steps if s["played"] and s["instruction"] in TURNS]

    # explore's rule three steps early (its plan ahead, best_shift's family): its first "turn" comes sooner (explore's
    # plan is imagined at the car's speed now, so not exactly 3 s sooner); a silent policy says nothing
    assert turns(lambda info: int(info["explore_future"][3]))[0] < turns(None)[0]
    assert turns(lambda info: 0) == []
