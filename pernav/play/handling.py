"""How the person's car handles: the truck's wheel is slower than the car's, as the simulated truck driver's is.

The person's controls already go through the vehicle's own limits (:class:`~pernav.world.drivers.VehicleModel`:
steering angle, emergency braking, acceleration, grip, length in the bicycle model), so a truck turns wider, brakes
and accelerates less. What the keys did not know is that a truck's steering responds more slowly: the simulated
driver's steering time constant is longer in the truck (:func:`pernav.world.drivers.resolve`). The same ratio
slows the person's wheel here: the rate a held key turns it and it returns to the centre, and a wheel's lag.

Only the given car changes (instance attributes over :class:`~pernav.world.driver_car.DriverCar`'s constants), and
only where ``pernav play`` calls this: simulated drives never read these constants (they steer through
``_act_simulated``), so study episodes are unchanged.

Example:
    >>> from pernav.world.drivers import Context, named_user, resolve
    >>> steering_lag_ratio(resolve(named_user("user1"), Context(vehicle="cybertruck")))
    1.25
    >>> steering_lag_ratio(resolve(named_user("user1"), Context()))
    1.0
"""

from __future__ import annotations

import dataclasses

from pernav.world.driver_car import DriverCar
from pernav.world.drivers import Driver, resolve

__all__ = ["apply_handling", "steering_lag_ratio"]


def steering_lag_ratio(driver: Driver) -> float:
    """How much slower ``driver``'s steering responds in its vehicle than the same person's in the car (camaro)."""
    in_car = resolve(driver.profile, dataclasses.replace(driver.context, vehicle="camaro"))
    return round(driver.steering_tau / in_car.steering_tau, 6)


def apply_handling(car: DriverCar) -> float:
    """Give ``car`` (the person's) its vehicle's steering response; returns the ratio applied (1.0 in the car)."""
    ratio = steering_lag_ratio(car.driver)
    car.KEY_STEER_RATE = DriverCar.KEY_STEER_RATE / ratio
    car.KEY_CENTRE_RATE = DriverCar.KEY_CENTRE_RATE / ratio
    car.WHEEL_LAG = DriverCar.WHEEL_LAG * ratio
    return ratio
