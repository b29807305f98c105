"""Former home of the navigation's model env: :mod:`pernav.model.navigation` (these names still import from here)."""

from pernav.model.navigation import ImaginedNavigationEnv, make_world_model, route_index

__all__ = ["ImaginedNavigationEnv", "make_world_model", "route_index"]
