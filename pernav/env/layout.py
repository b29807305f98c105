"""Constants of the planning context's layout (``route_ahead``), in a module that loads no highway-env.

>>> ROUTE_SPACING, ROUTE_BEHIND
(3.0, 15.0)
"""

ROUTE_SPACING = 3.0  # m between the points of ``route_ahead``
ROUTE_BEHIND = 15.0  # m of route behind the car included in ``route_ahead``
