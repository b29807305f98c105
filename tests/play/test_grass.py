"""Off the road the grass slows the person's car (:mod:`pernav.play.handling`), and nothing else changes: the car on
the road, and every simulated drive."""

from __future__ import annotations

import numpy as np
import pytest

from pernav.play.controls import ScriptedControls
from pernav.play.handling import GRASS_SPEED, apply_handling, grass_drag
from pernav.world.controls import ControlInput, PersonAtTheWheel
from pernav.world.driver_car import DriverCar
from pernav.world.drivers import Context, named_user, resolve
from pernav.world.simulation import World
from pernav.world.towns import get_town

KMH = 3.6


class FullThrottle:
    """A person holding the throttle pedal down, the wheel straight."""

    keeps_lanes = False

    def read(self, car: DriverCar) -> ControlInput:
        return ControlInput(throttle=1.0)


def _world(vehicle: str = "camaro", n_traffic: int = 0) -> World:
    town = get_town("Town1")
    return World(town, resolve(named_user("user1"), Context(vehicle=vehicle)), town.routes[0], seed=0,
                 n_traffic=n_traffic)


def _on_the_grass(world: World, speed: float) -> None:
    """The car 30 m east of the town's last road, heading east (away from every road) at ``speed`` m/s."""
    town = world.town
    east = max(max(town.lane(i).position(0.0, 0.0)[0], town.lane(i).position(town.lane(i).length, 0.0)[0])
               for i in town.successors)
    north = np.mean([town.lane(i).position(0.0, 0.0)[1] for i in town.successors])
    world.ego.position, world.ego.heading, world.ego.speed = np.array([east + 30.0, north]), 0.0, speed


def _full_throttle_on_grass(vehicle: str, person: bool, frames: int = 300) -> list[tuple[bool, float]]:
    """(off the road, km/h) after each frame of full throttle on the grass, starting at 85 km/h; ``person``: with
    the person's handling (as ``pernav play`` gives it)."""
    world = _world(vehicle)
    world.ego.external = FullThrottle()
    if person:
        apply_handling(world.ego)
    _on_the_grass(world, 85.0 / KMH)
    log = []
    for _ in range(frames):
        world.frame()
        log.append((world.ego.off_road, world.ego.speed * KMH))
    return log


@pytest.mark.parametrize(("vehicle", "settles_kmh"), [("camaro", 30.0), ("cybertruck", 16.3)])
def test_full_throttle_on_grass_settles_far_below_road_speeds(vehicle, settles_kmh):
    """85 km/h onto the grass (the kerb strike takes 40 %: 51 km/h), throttle held for 30 s: the person's car settles
    at 30 km/h (truck 16 km/h); without the grass it would have gained 2.5 m/s^2 all along, to 320 km/h."""
    grass = _full_throttle_on_grass(vehicle, person=True)
    bare = _full_throttle_on_grass(vehicle, person=False)
    assert all(off for off, _ in grass) and all(off for off, _ in bare)  # the grass all the way
    speeds = [kmh for _, kmh in grass]
    assert speeds[0] < 52.0 and all(b < a for a, b in zip(speeds[:100], speeds[1:100], strict=False))  # slows at once
    assert speeds[-1] == pytest.approx(settles_kmh, abs=0.5)
    assert bare[-1][1] > 230.0 and bare[99][1] > 2 * speeds[99]


def test_the_grass_model():
    """Full throttle in the car balances the grass at GRASS_SPEED; the brakes and the grass together stay within
    the emergency deceleration; a car at rest is held, not pushed back."""
    world = _world()
    car = world.ego
    apply_handling(car)
    car.off_road, car.speed = True, GRASS_SPEED
    assert car.accel_of(ControlInput(throttle=1.0)) == pytest.approx(0.0, abs=1e-9)
    car.speed = 20.0
    assert car.accel_of(ControlInput(brake=1.0)) == -car.driver.vehicle.max_decel
    assert car.accel_of(ControlInput()) == pytest.approx(-DriverCar.ROLLING - grass_drag(20.0))
    car.speed = 0.0
    assert car.accel_of(ControlInput()) == 0.0 and car.accel_of(ControlInput(throttle=1.0)) > 1.0
    car.off_road, car.speed = False, 20.0
    for inputs in (ControlInput(throttle=1.0), ControlInput(brake=1.0), ControlInput(), ControlInput(throttle=0.4)):
        assert car.accel_of(inputs) == DriverCar.accel_of(car, inputs)  # on the road: the pedals as before


def _frames(world: World, n: int) -> list[tuple]:
    out = []
    for _ in range(n):
        world.frame()
        ego = world.ego
        out.append((*ego.position.tolist(), ego.heading, ego.speed, ego.accel, ego.steer, ego.off_road))
    return out


def test_on_the_road_the_person_drives_as_before():
    """The scripted bot drives 40 s of route 0 with traffic: the same frames with the grass handling as without."""
    drives = []
    for person in (False, True):
        world = _world(n_traffic=4)
        world.ego.external = ScriptedControls()
        if person:
            apply_handling(world.ego)
        drives.append(_frames(world, 400))
    assert not any(frame[-1] for frame in drives[1])  # on the road throughout
    assert max(frame[3] for frame in drives[1]) > 8.0  # and driving, not standing
    assert drives[0] == drives[1]


def test_a_simulated_drive_is_unchanged_even_on_grass():
    """The simulated driver's car on the grass: the same frames whether or not it was given the person's handling
    (a simulated drive never asks for the pedals' acceleration); and the class is left as it was."""
    drives = []
    for handled in (False, True):
        world = _world(n_traffic=2)
        if handled:
            apply_handling(world.ego)
        _on_the_grass(world, 50.0 / KMH)
        drives.append(_frames(world, 100))
    assert drives[0][0][-1]  # it was off the road
    assert drives[0] == drives[1]
    assert "accel_of" not in vars(_world().ego) and DriverCar.accel_of is PersonAtTheWheel.accel_of
