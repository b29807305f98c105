"""The world's constants that the learning side needs (town names, waypoint spacing, the instructions and their
spoken durations), in a module that loads no highway-env.

>>> TOWN_NAMES[0], WAYPOINT_SPACING
('Town1', 2.0)
"""

TOWN_NAMES = ("Town1", "Town2", "Town3", "Town4", "Town5")
WAYPOINT_SPACING = 2.0  # metres between route waypoints
GOAL_LOOKAHEAD_S = 1.0  # goal waypoint = where the car would be after one policy step at its speed

# The instructions the navigation speaks, their playback speeds and spoken durations (pernav.play's audio files
# are made to these lengths)
ACTION_NAMES = (
    "no instruction",
    "turn left",
    "turn right",
    "prepare to turn left",
    "prepare to turn right",
    "enter the roundabout",
    "keep left",
)
PLAYBACK = ("slower", "normal", "faster")
PLAYBACK_SCALE = {"slower": 1.3, "normal": 1.0, "faster": 0.75}
AUDIO_DURATION = (0.0, 1.2, 1.2, 1.9, 1.9, 1.6, 1.2)  # seconds at normal playback
N_INSTRUCTIONS = len(ACTION_NAMES)
TURN_INSTRUCTIONS = (1, 2, 3, 4, 5, 6)  # everything but silence refers to a junction or a roundabout


def audio_duration(instruction: int, playback: str = "normal") -> float:
    """Spoken duration of an instruction at a playback speed.

    >>> audio_duration(1, "normal")
    1.2
    """
    return AUDIO_DURATION[instruction] * PLAYBACK_SCALE[playback]
