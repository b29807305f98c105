"""The Simulator Sickness Questionnaire (Kennedy, Lane, Berbaum and Lilienthal 1993), built into a lab session: 16
symptoms, each rated 0 (none), 1 (slight), 2 (moderate) or 3 (severe), and its three subscales and total score.

Each symptom loads on one or two of the subscales nausea (N), oculomotor (O) and disorientation (D); a subscale's
raw score is the sum of its symptoms' ratings, weighted by the published factors: N x 9.54, O x 7.58, D x 13.92, and
the total is (N + O + D raw sums) x 3.74.

Example:
    >>> ratings = {item.id: 0 for item in ITEMS}
    >>> ratings["ssq_nausea"] = 2   # loads on N and D
    >>> scores(ratings)
    {'ssq_nausea_score': 19.08, 'ssq_oculomotor_score': 0.0, 'ssq_disorientation_score': 27.84, 'ssq_total': 14.96}
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["ITEMS", "RATINGS", "SCALE", "SCORES", "WEIGHTS", "SsqItem", "scores"]

#: the rating scale of every symptom (inclusive) and its words
SCALE = (0, 3)
RATINGS = ("none", "slight", "moderate", "severe")
#: the published weights of the subscales' raw sums and of the total (of the three raw sums together)
WEIGHTS = {"nausea": 9.54, "oculomotor": 7.58, "disorientation": 13.92, "total": 3.74}
#: the score columns, in order
SCORES = ("ssq_nausea_score", "ssq_oculomotor_score", "ssq_disorientation_score", "ssq_total")


@dataclass(frozen=True)
class SsqItem:
    """One symptom: its answer id, its words, and the subscales it loads on (N, O, D)."""

    id: str
    text: str
    loads: str


ITEMS = (
    SsqItem("ssq_general_discomfort", "General discomfort", "NO"),
    SsqItem("ssq_fatigue", "Fatigue", "O"),
    SsqItem("ssq_headache", "Headache", "O"),
    SsqItem("ssq_eyestrain", "Eyestrain", "O"),
    SsqItem("ssq_difficulty_focusing", "Difficulty focusing", "OD"),
    SsqItem("ssq_increased_salivation", "Increased salivation", "N"),
    SsqItem("ssq_sweating", "Sweating", "N"),
    SsqItem("ssq_nausea", "Nausea", "ND"),
    SsqItem("ssq_difficulty_concentrating", "Difficulty concentrating", "NO"),
    SsqItem("ssq_fullness_of_head", "Fullness of head", "D"),
    SsqItem("ssq_blurred_vision", "Blurred vision", "OD"),
    SsqItem("ssq_dizzy_eyes_open", "Dizziness with eyes open", "D"),
    SsqItem("ssq_dizzy_eyes_closed", "Dizziness with eyes closed", "D"),
    SsqItem("ssq_vertigo", "Vertigo", "D"),
    SsqItem("ssq_stomach_awareness", "Stomach awareness", "N"),
    SsqItem("ssq_burping", "Burping", "N"),
)


def scores(ratings: Mapping[str, int]) -> dict[str, float]:
    """The subscale and total scores of the 16 ratings (``{item id: 0..3}``; a missing or out-of-range rating is a
    ValueError naming it)."""
    raw = {"N": 0, "O": 0, "D": 0}
    for item in ITEMS:
        value = ratings.get(item.id)
        if isinstance(value, bool) or not isinstance(value, int) or not SCALE[0] <= value <= SCALE[1]:
            raise ValueError(f"SSQ rating {item.id!r}: expected a whole number 0-3, got {value!r}")
        for scale in item.loads:
            raw[scale] += value
    return {"ssq_nausea_score": round(raw["N"] * WEIGHTS["nausea"], 2),
            "ssq_oculomotor_score": round(raw["O"] * WEIGHTS["oculomotor"], 2),
            "ssq_disorientation_score": round(raw["D"] * WEIGHTS["disorientation"], 2),
            "ssq_total": round((raw["N"] + raw["O"] + raw["D"]) * WEIGHTS["total"], 2)}
