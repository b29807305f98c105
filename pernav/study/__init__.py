"""The online meta-learning study (Algorithm 1 with every method), its schedule, presets and report.

The names below load on first use, so that a light part (``pernav.study.stats``, numpy only) imports without
the study's runner and its simulator.
"""

from pernav._lazy import lazy_exports

_EXPORTS = {
    **{name: "pernav.study.config" for name in ("METHODS", "PRESETS", "PresetError", "StudyConfig", "preset")},
    **{name: "pernav.study.schedule"
       for name in ("Entry", "ScheduleError", "load_schedule", "paper_schedule", "parse_schedule")},
    **{name: "pernav.study.study" for name in ("OutputError", "run_study")},
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
