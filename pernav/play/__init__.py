"""Interactive play (``pernav play``): a person drives a town, hears the prompts, and the drive is recorded as data.

The names below load on first use (importing ``pernav.play`` loads neither pygame nor highway-env).
"""

from pernav._lazy import lazy_exports

_EXPORTS = {
    "BeliefSession": "pernav.play.believe",
    "JoystickControls": "pernav.play.controls",
    "KeyboardControls": "pernav.play.controls",
    "PLAY_POLICIES": "pernav.play.options",
    "PersonalSession": "pernav.play.personal",
    "PlayError": "pernav.play.options",
    "PlayOptions": "pernav.play.options",
    "PlayResult": "pernav.play.framelog",
    "PlaySession": "pernav.play.loop",
    "ScriptedControls": "pernav.play.controls",
    "SessionKeys": "pernav.play.controls",
    "SessionOptions": "pernav.play.sessions",
    "open_speaker": "pernav.play.loop",
    "parse_axes": "pernav.play.controls",
    "load_drive": "pernav.trainer.drives",
    "save_drive": "pernav.trainer.drives",
    "session_class": "pernav.play.believe",
    "study_policy": "pernav.play.personal",
    "Speaker": "pernav.play.audio",
    "speech_file": "pernav.play.audio",
    "wav_duration": "pernav.play.audio",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
