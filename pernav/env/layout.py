"""Constants of the observation's and the planning context's (``route_ahead``) layout, in a module that loads no
highway-env.

>>> ROUTE_SPACING, ROUTE_BEHIND, STATE_KEYS.index("brake")
(3.0, 15.0, 13)
"""

#: the entries of the navigation's observation ``[STATE_DIM]``, in order (read them by name: ``STATE_KEYS.index``)
STATE_KEYS = ("x", "y", "z", "vx", "vy", "vz", "heading", "junction", "roundabout", "goal_x", "goal_y",
              "steering", "reverse", "brake")
STATE_DIM = len(STATE_KEYS)

ROUTE_SPACING = 3.0  # m between the points of ``route_ahead``
ROUTE_BEHIND = 15.0  # m of route behind the car included in ``route_ahead``
