"""The online meta-learning study (Algorithm 1 with every method), its schedule, presets and report."""

from pernav.study.config import METHODS, PRESETS, PresetError, StudyConfig, preset
from pernav.study.schedule import Entry, ScheduleError, load_schedule, paper_schedule, parse_schedule
from pernav.study.study import OutputError, run_study

__all__ = [
    "METHODS",
    "PRESETS",
    "Entry",
    "OutputError",
    "PresetError",
    "ScheduleError",
    "StudyConfig",
    "load_schedule",
    "paper_schedule",
    "parse_schedule",
    "preset",
    "run_study",
]
