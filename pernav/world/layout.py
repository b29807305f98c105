"""Constants of the world's layout that the learning side needs, in a module that loads no highway-env.

>>> TOWN_NAMES[0], WAYPOINT_SPACING
('Town1', 2.0)
"""

TOWN_NAMES = ("Town1", "Town2", "Town3", "Town4", "Town5")
WAYPOINT_SPACING = 2.0  # metres between route waypoints
GOAL_LOOKAHEAD_S = 1.0  # goal waypoint = where the car would be after one policy step at its speed
