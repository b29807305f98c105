"""How the person's car handles: the truck's wheel is slower than the car's, as the simulated truck driver's is; off
the road the grass slows the car.

The person's controls already go through the vehicle's own limits (:class:`~pernav.world.drivers.VehicleModel`:
steering angle, emergency braking, acceleration, grip, length in the bicycle model), so a truck turns wider, brakes
and accelerates less. What the keys did not know is that a truck's steering responds more slowly: the simulated
driver's steering time constant is longer in the truck (:func:`pernav.world.drivers.resolve`). The same ratio
slows the person's wheel here: the rate a held key turns it and it returns to the centre, and a wheel's lag.

Nor did they know the grass: the world counts a kerb strike when the car leaves the road (``car.off_road``) and
the car drove on across the grass at road speed, since a pedal's acceleration is the same on any ground. Off the
road the grass's drag is taken from the acceleration the pedals ask for (:func:`grass_drag`): the rolling
resistance of turf, and a drag that grows with speed, so that full throttle settles at :data:`GRASS_SPEED`.

Only the given car changes (instance attributes over :class:`~pernav.world.driver_car.DriverCar`'s constants and
its ``accel_of``), and only where ``pernav play`` calls this: simulated drives never read these (they steer and
pedal through ``_act_simulated``), so study episodes are unchanged.

Example:
    >>> from pernav.world.drivers import Context, named_user, resolve
    >>> steering_lag_ratio(resolve(named_user("user1"), Context(vehicle="cybertruck")))
    1.25
    >>> steering_lag_ratio(resolve(named_user("user1"), Context()))
    1.0
    >>> round(grass_drag(0.0), 2), round(grass_drag(GRASS_SPEED), 2)  # m/s^2: at rest, and where full throttle is
    (0.85, 2.5)
"""

from __future__ import annotations

import dataclasses
import types

from pernav.world.controls import ControlInput, PersonAtTheWheel
from pernav.world.driver_car import DriverCar
from pernav.world.drivers import Driver, resolve

__all__ = ["GRASS_SPEED", "apply_handling", "grass_drag", "steering_lag_ratio"]

GRAVITY = 9.81  # m/s^2
# rolling-resistance coefficients (dimensionless, force / weight) of a car tyre: on concrete or new asphalt
# 0.010-0.015 (Engineering ToolBox, "Rolling Resistance"); on medium-hard soil 0.08, on sand 0.1-0.2 (Carvill 1993,
# Mechanical Engineer's Data Handbook); turf over soil taken between the two. The road's own share is already in the
# pedals' net acceleration (and in the coasting drag ``ROLLING``): the grass adds the difference.
ASPHALT_RR = 0.013
GRASS_RR = 0.10
# m/s (30 km/h) where full throttle settles on grass in the car (accel_scale 1). The pedals' acceleration does not
# fall with speed (no engine power or air-drag limit in the model), so a constant rolling resistance alone would let
# full throttle still gain speed on grass; the part of the drag that grows with speed (long grass ploughed through,
# uneven ground the suspension absorbs, wheels slipping on turf) is sized from this speed, a chosen one at which a
# car is driven across a field, not a measured one. A truck (accel_scale 0.7) settles at 16 km/h.
GRASS_SPEED = 30.0 / 3.6
GRASS_DRAG_RATE = (PersonAtTheWheel.KEY_THROTTLE - GRAVITY * (GRASS_RR - ASPHALT_RR)) / GRASS_SPEED  # 1/s, ~0.2


def steering_lag_ratio(driver: Driver) -> float:
    """How much slower ``driver``'s steering responds in its vehicle than the same person's in the car (camaro)."""
    in_car = resolve(driver.profile, dataclasses.replace(driver.context, vehicle="camaro"))
    return round(driver.steering_tau / in_car.steering_tau, 6)


def grass_drag(speed: float) -> float:
    """Deceleration (m/s^2) the grass adds over the road's at ``speed`` (m/s): turf's extra rolling resistance plus
    a drag proportional to speed."""
    return GRAVITY * (GRASS_RR - ASPHALT_RR) + GRASS_DRAG_RATE * max(speed, 0.0)


def _accel_on_ground(car: DriverCar, inputs: ControlInput) -> float:
    """``car.accel_of`` for the person's car: the pedals' acceleration, less the grass's drag while off the road.
    The brakes and the grass together decelerate no harder than the vehicle's emergency braking (the tyres' grip),
    and at rest the grass holds the car without pushing it back."""
    accel = DriverCar.accel_of(car, inputs)
    if not car.off_road:
        return accel
    slowed = accel - grass_drag(car.speed)
    floor = min(accel, 0.0) if car.speed <= 0.0 else min(accel, -car.driver.vehicle.max_decel)
    return max(slowed, floor)


def apply_handling(car: DriverCar) -> float:
    """Give ``car`` (the person's) its vehicle's steering response and the grass's drag off the road; returns the
    steering ratio applied (1.0 in the car)."""
    ratio = steering_lag_ratio(car.driver)
    car.KEY_STEER_RATE = PersonAtTheWheel.KEY_STEER_RATE / ratio  # the person's wheel, not a simulated driver's keys
    car.KEY_CENTRE_RATE = PersonAtTheWheel.KEY_CENTRE_RATE / ratio
    car.WHEEL_LAG = PersonAtTheWheel.WHEEL_LAG * ratio
    car.accel_of = types.MethodType(_accel_on_ground, car)  # this car only: the class's own is left as it is
    return ratio
