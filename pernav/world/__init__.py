"""The simulated world: towns, routes, drivers, traffic and the tracking cost."""

from pernav.world.cost import tracking_cost
from pernav.world.drivers import (
    CONTEXT_CHOICES,
    NAMED_USERS,
    PROFILE_RANGES,
    Context,
    Driver,
    DriverProfile,
    Population,
    ProfileError,
    named_user,
    resolve,
)
from pernav.world.routing import Route, RouteError, astar, plan_route
from pernav.world.towns import TOWN_NAMES, Town, TownError, get_town

__all__ = [
    "CONTEXT_CHOICES",
    "NAMED_USERS",
    "PROFILE_RANGES",
    "Context",
    "Driver",
    "DriverProfile",
    "Population",
    "ProfileError",
    "Route",
    "RouteError",
    "TOWN_NAMES",
    "Town",
    "TownError",
    "astar",
    "get_town",
    "named_user",
    "plan_route",
    "resolve",
    "tracking_cost",
]
