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
#: the speeds (m/s) and the points ahead (every ``ROUTE_SPACING`` m from the car) of the explore table, what explore's
#: rule says at each (:func:`pernav.env.planning.explore_table`; the env's ``explore_table`` option)
EXPLORE_SPEEDS = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0)
EXPLORE_POINTS = 81
