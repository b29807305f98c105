"""An episode job's policy specs and adapt_driver's evidence job (what its rollouts run on the study's executor)."""

import dataclasses

import pytest
import torch

from pernav.env.torchrl_env import explore_module
from pernav.learners.belief import AnswerDetector
from pernav.learners.driver import DriverBelief, DriverPrior, DriverTracker
from pernav.learners.outcomes import SwerveDetector
from pernav.planner.retiming import RetimedExplore
from pernav.study.config import preset
from pernav.study.episodes import EpisodeJob, make_policy, run_evidence_job


def test_the_collector_spec_is_explore_or_explore_retimed_as_the_study_collects():
    cfg = preset("smoke")
    for collect, kind in (("explore", type(explore_module())), ("retimed", RetimedExplore)):
        job = EpisodeJob(dataclasses.replace(cfg, collect=collect), "Town1", cfg.schedule[0], 0, 3, "collector")
        assert isinstance(make_policy(job), kind), collect


@pytest.mark.slow
def test_an_evidence_job_reads_its_drive_with_a_copy_and_gives_the_same_evidence_every_time():
    cfg = preset("smoke")
    prior = DriverPrior.population((0.3, 0.4), (2.4, 0.7))
    tracker = DriverTracker(AnswerDetector(), DriverBelief(prior), SwerveDetector())
    jobs = [EpisodeJob(cfg, "Town1", cfg.schedule[-1], 0, 5, policy, params=tracker) for policy in ("driver", "collector")]
    for job in jobs:
        first, again = run_evidence_job(job), run_evidence_job(job)
        assert len(first) > 0, job.policy  # the drive's prompts were read
        assert len(first.answers) == len(again.answers) and len(first.outcomes) == len(again.outcomes)
        for (d, p, n), (d2, p2, n2) in zip(first.answers, again.answers, strict=True):
            assert torch.equal(d, d2) and torch.equal(p, p2) and n == n2, job.policy
    assert len(tracker.belief.evidence) == 0  # the tracker the jobs carry is not the one that read the drives
