"""The simulated world: towns, routes, drivers, traffic and the tracking cost.

The names below load on first use, so that the learning side can import a light module (``pernav.world.cost``,
``pernav.world.constants``) without highway-env.
"""

from pernav._lazy import lazy_exports

_EXPORTS = {
    "tracking_cost": "pernav.world.cost",
    "CONTEXT_CHOICES": "pernav.world.drivers",
    "NAMED_USERS": "pernav.world.drivers",
    "PROFILE_RANGES": "pernav.world.drivers",
    "Context": "pernav.world.drivers",
    "Driver": "pernav.world.drivers",
    "DriverProfile": "pernav.world.drivers",
    "Population": "pernav.world.drivers",
    "ProfileError": "pernav.world.drivers",
    "named_user": "pernav.world.drivers",
    "resolve": "pernav.world.drivers",
    "Route": "pernav.world.routing",
    "RouteError": "pernav.world.routing",
    "astar": "pernav.world.routing",
    "plan_route": "pernav.world.routing",
    "Town": "pernav.world.network",
    "TownError": "pernav.world.towns",
    "get_town": "pernav.world.towns",
    "TOWN_NAMES": "pernav.world.constants",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
