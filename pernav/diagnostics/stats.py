"""Paired comparisons with 95 % bootstrap confidence intervals: the study's own, defined in
:mod:`pernav.study.stats` (the study judges its methods with them) and importable from here as well.

Example:
    >>> paired_difference([3.0, 4.0], [1.0, 2.0])["mean"]
    2.0
"""

from pernav.study.stats import bootstrap_ci, gap_closed, paired_difference, paired_ratio

__all__ = ["bootstrap_ci", "gap_closed", "paired_difference", "paired_ratio"]
