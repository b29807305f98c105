"""The world's constants that the learning side needs (town names, waypoint spacing, the instructions and their
spoken durations), in a module that loads no highway-env.

>>> TOWN_NAMES[0], WAYPOINT_SPACING
('Town1', 2.0)
>>> ACTION_NAMES[Instruction.PREPARE_LEFT], OPPOSITE[Instruction.TURN_LEFT] == 2
('prepare to turn left', True)
"""

import enum

TOWN_NAMES = ("Town1", "Town2", "Town3", "Town4", "Town5")
WAYPOINT_SPACING = 2.0  # metres between route waypoints
GOAL_LOOKAHEAD_S = 1.0  # goal waypoint = where the car would be after one policy step at its speed


class Instruction(enum.IntEnum):
    """The instructions the navigation speaks, by their index in the env's 7-action space (an ``int``: members
    compare and hash as their values, so ``instruction in TURNS`` holds for a plain ``1`` too)."""

    NONE = 0  # no instruction: silence
    TURN_LEFT = 1
    TURN_RIGHT = 2  # also a roundabout's exit ("turn right" off the ring)
    PREPARE_LEFT = 3
    PREPARE_RIGHT = 4
    ENTER_ROUNDABOUT = 5
    KEEP_LEFT = 6  # stay on the ring past an exit


TURNS = (Instruction.TURN_LEFT, Instruction.TURN_RIGHT)
PREPARES = (Instruction.PREPARE_LEFT, Instruction.PREPARE_RIGHT)
#: the instructions that name a side: a driver may mishear them as the other side, and drops those heard before a
#: junction box on entering it (they were meant for that junction)
SIDED = (*TURNS, *PREPARES)
OPPOSITE = {Instruction.TURN_LEFT: Instruction.TURN_RIGHT, Instruction.TURN_RIGHT: Instruction.TURN_LEFT,
            Instruction.PREPARE_LEFT: Instruction.PREPARE_RIGHT, Instruction.PREPARE_RIGHT: Instruction.PREPARE_LEFT}
SIDE = {Instruction.TURN_LEFT: "left", Instruction.TURN_RIGHT: "right",
        Instruction.PREPARE_LEFT: "left", Instruction.PREPARE_RIGHT: "right"}

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
N_INSTRUCTIONS = len(ACTION_NAMES)  # the action space of the navigation: 7 instructions
N_PLAYBACKS = len(PLAYBACK)
N_ADAPTIVE_ACTIONS = N_INSTRUCTIONS * N_PLAYBACKS  # with ``adaptive_speed``: each instruction at each playback, 21
# everything but silence refers to a junction or a roundabout
TURN_INSTRUCTIONS = tuple(i for i in Instruction if i != Instruction.NONE)


def n_actions(adaptive_speed: bool) -> int:
    """The size of the navigation's action space: the instructions, or each at each playback speed.

    >>> n_actions(False), n_actions(True)
    (7, 21)
    """
    return N_ADAPTIVE_ACTIONS if adaptive_speed else N_INSTRUCTIONS


def audio_duration(instruction: int, playback: str = "normal") -> float:
    """Spoken duration of an instruction at a playback speed.

    >>> audio_duration(Instruction.TURN_LEFT, "normal")
    1.2
    """
    return AUDIO_DURATION[instruction] * PLAYBACK_SCALE[playback]
