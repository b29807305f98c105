"""Learners of a driver's prompt timing that are not dynamics models (the paper's learners live in
:mod:`pernav.model`, :mod:`pernav.planner` and :mod:`pernav.trainer`).

- :mod:`pernav.learners.timing`: ``TimingModel``, a ridge regression of the driver's timing from one drive's
  features (the population baseline ``timing``);
- :mod:`pernav.learners.belief`: the ``belief`` learner: ``AnswerDetector`` reads when each prompt took effect,
  ``ReactionBelief`` holds a posterior over the driver's reaction and decision times, ``BeliefTracker`` updates it
  within a drive;
- :mod:`pernav.learners.outcomes`: whether a "turn" prompt came in time (``SwerveDetector``, ``turn_outcomes``);
- :mod:`pernav.learners.answers`: the belief's offline data, simulated drivers whose answers are labelled.

Example:
    >>> from pernav.learners import ReactionBelief
    >>> ReactionBelief(prior_mean=1.0, prior_sd=0.3).mean > 0
    True
"""

from pernav.learners.answers import fit_belief, labelled_drives
from pernav.learners.belief import AnswerDetector, BeliefTracker, DecisionPrior, ReactionBelief
from pernav.learners.outcomes import SwerveDetector, turn_outcomes
from pernav.learners.timing import TimingModel, timing_features

__all__ = ["AnswerDetector", "BeliefTracker", "DecisionPrior", "ReactionBelief", "SwerveDetector", "TimingModel",
           "fit_belief", "labelled_drives", "timing_features", "turn_outcomes"]
