"""The play window's views: top, third_person (heading-up chase), first_person (driver's seat), fog.

Headless: every view draws on an off-screen pygame surface; the pictures are read back as pixel arrays.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from play_helpers import FrameScript

from pernav.world.controls import ControlInput

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # windows drawn off screen
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

pygame = pytest.importorskip("pygame")

from pernav.play.camera_base import Fog, Frame  # noqa: E402
from pernav.play.cameras import CAMERAS, CHASE_ANCHOR, make_camera  # noqa: E402
from pernav.play.loop import PlaySession  # noqa: E402
from pernav.play.options import PlayOptions  # noqa: E402
from pernav.play.scene import PALETTE  # noqa: E402
from pernav.world.towns import get_town  # noqa: E402

SIZE = (480, 360)
SCALING = 6.0


def _pixels(surface) -> np.ndarray:
    """``[W, H, 3]`` colours of a surface (x first, as pygame.surfarray)."""
    return pygame.surfarray.array3d(surface)


def _mask(image: np.ndarray, colour: str) -> np.ndarray:
    return (image == PALETTE[colour]).all(-1)


def _approach(kind: str = "left", heading_deg: float = 90.0, before: float = 20.0, after: float = 60.0):
    """A frame of Town1 with the car ``before`` metres ahead of a ``kind`` turn it approaches at ``heading_deg``
    (90: south, y down), the route drawn from the car to ``after`` metres past the turn."""
    town = get_town("Town1")
    for route in town.routes:
        for m in route.manoeuvres:
            if m.kind != kind or not m.decision:
                continue
            i = int(np.searchsorted(route.s, m.s - before))
            d = route.waypoints[i + 1] - route.waypoints[i]
            heading = math.atan2(d[1], d[0])
            if abs(math.degrees(heading) - heading_deg) < 1.0:
                ahead = (route.s >= m.s - before) & (route.s <= m.s + after)
                return town, Frame(ego=route.waypoints[i], heading=heading, route=route.waypoints[ahead])
    raise AssertionError(f"no {kind} turn approached at {heading_deg} degrees in Town1")


def _draw(name: str, town, frame: Frame, fog: Fog | None = None) -> np.ndarray:
    out = pygame.Surface(SIZE)
    make_camera(name, town, SIZE).draw(out, frame, fog)
    return _pixels(out)


def test_chase_view_bends_a_left_turn_to_the_left():
    """Heading south, 'turn left' goes east: the north-up map shows it bending right (the trouble with it); the chase view,
    heading up, shows it bending left of the car's column."""
    town, frame = _approach("left", 90.0)
    car_x, car_y = SIZE[0] / 2, CHASE_ANCHOR * SIZE[1]
    image = _draw("third_person", town, frame)
    xs, ys = np.nonzero(_mask(image, "route"))
    beyond = ys < car_y - 30 * SCALING  # more than 30 m ahead: past the turn (20 m ahead)
    assert beyond.sum() > 30
    assert xs[beyond].mean() < car_x - 10 * SCALING  # well left of the car's column
    near = (ys < car_y - 2 * SCALING) & (ys > car_y - 15 * SCALING)  # before the turn: straight up from the car
    assert abs(xs[near].mean() - car_x) < 2 * SCALING
    # the north-up map, nearer the turn (its exit on the screen): the turn goes to the screen's right
    town, frame = _approach("left", 90.0, before=8.0)
    xs, ys = np.nonzero(_mask(_draw("top", town, frame), "route"))
    beyond = ys > SIZE[1] / 2 + 12 * SCALING  # past the turn, below the car
    assert beyond.sum() > 30 and xs[beyond].mean() > SIZE[0] / 2 + 10 * SCALING


def test_chase_view_right_turn_bends_right():
    town, frame = _approach("right", 0.0)  # heading east
    image = _draw("third_person", town, frame)
    xs, ys = np.nonzero(_mask(image, "route"))
    beyond = ys < CHASE_ANCHOR * SIZE[1] - 30 * SCALING
    assert beyond.sum() > 30 and xs[beyond].mean() > SIZE[0] / 2 + 10 * SCALING


def test_top_view_is_the_north_up_map_centred_on_the_car():
    """The top view as before: north up, the car at the screen's centre, 6 pixels per metre."""
    town, frame = _approach("left", 90.0)
    image = _draw("top", town, frame)
    route = _mask(image, "route")
    for point in frame.route[5:40:7]:  # each route point where the map puts it
        x, y = np.round((point - frame.ego) * SCALING + np.array(SIZE) / 2).astype(int)
        if 0 <= x < SIZE[0] and 0 <= y < SIZE[1]:
            assert route[x - 2:x + 3, y - 2:y + 3].any(), point
    assert _mask(image, "road")[SIZE[0] // 2 + 6, SIZE[1] // 2]  # the car is on the road at the centre (a metre
    # to its side: the route is drawn along the lane's middle)
    assert _mask(image, "offroad").sum() > 0.3 * SIZE[0] * SIZE[1]  # grass around the streets, not grey


def test_road_kerb_offroad_and_markings_differ():
    town, frame = _approach("left", 90.0, before=8.0)
    image = _draw("top", town, frame)
    counts = {name: int(_mask(image, name).sum()) for name in ("road", "kerb", "offroad", "marking", "box")}
    assert all(v > 50 for v in counts.values()), counts  # each drawn, in its own colour
    assert len({PALETTE[n] for n in counts}) == len(counts)


def test_first_person_has_a_horizon_sky_above_road_below():
    town, frame = _approach("left", 90.0, before=60.0)
    frame.route = np.zeros((0, 2))
    camera = make_camera("first_person", town, SIZE)
    out = pygame.Surface(SIZE)
    camera.draw(out, frame)
    image = _pixels(out)
    horizon = int(camera.horizon)
    assert _mask(image[:, : horizon - 2], "sky").mean() > 0.95  # sky above (the HUD is not drawn here)
    assert not _mask(image[:, horizon + 2:], "sky").any()  # and none below
    below = image[SIZE[0] // 2, horizon + 20: int(0.85 * SIZE[1])]  # straight ahead, down to the bonnet
    assert _mask(below[None], "road").mean() > 0.9
    assert _mask(image, "marking").sum() > 20  # the dashed centre line and the stop line ahead


def test_first_person_sees_the_left_turn_to_the_left_and_other_cars():
    from pernav.play.camera_base import CarShape

    town, frame = _approach("left", 90.0, before=20.0)
    ahead = frame.ego + 12.0 * frame.forward
    frame.cars = [CarShape(ahead, frame.heading, 4.6, 1.9, (100, 200, 255))]
    image = _draw("first_person", town, frame)
    xs, _ = np.nonzero(_mask(image, "route"))
    assert xs.size > 100 and xs.min() < SIZE[0] / 2 - 50  # the route leaves to the left
    car = (np.abs(image.astype(int) - (100, 200, 255)).sum(-1) < 120) & ~_mask(image, "sky")
    assert car.sum() > 100  # the car ahead, as a box


@pytest.mark.parametrize("name", CAMERAS)
def test_fog_hides_the_route_far_away(name):
    """Beyond the fog's opaque distance nothing of the route is seen; nearer, some of it still is."""
    town, frame = _approach("left", 90.0, before=60.0, after=40.0)
    fog = Fog.for_visual("foggy", name)
    assert 25.0 <= fog.opaque <= 60.0  # the simulated driver's sight in fog (38 m x the camera's factor)
    camera = make_camera(name, town, (960, 720))  # the window's size: the map's 6 px/m reach beyond the fog
    out = pygame.Surface((960, 720))
    clear, foggy = [], []
    for veil, store in ((None, clear), (fog, foggy)):
        camera.draw(out, frame, veil)
        xs, ys = np.nonzero(_mask(_pixels(out), "route"))
        if name == "first_person":  # far is near the horizon: rows above the road seen at the opaque distance
            far = ys < camera.horizon + camera.focal * camera.eye_height / fog.opaque
        else:
            anchor = camera.anchor_px
            far = np.hypot(xs - anchor[0], ys - anchor[1]) > fog.opaque * SCALING + 2
        store += [int(far.sum()), int((~far).sum())]
    assert clear[0] > 20 and foggy[0] == 0  # far: seen when clear, hidden in fog
    assert foggy[1] > 0  # near: still seen


def test_fog_is_only_for_foggy():
    assert Fog.for_visual("normal", "top") is None and Fog.for_visual("rgb", "first_person") is None
    sights = [Fog.for_visual("foggy", c).opaque for c in ("first_person", "third_person", "top")]
    assert sights == sorted(sights)  # the driver's seat sees least far, the map most (pernav.world.drivers)


@pytest.mark.parametrize(("camera", "visual"), [("top", "normal"), ("third_person", "foggy"),
                                                ("first_person", "normal")])
def test_play_view_follows_the_drive_context(camera, visual):
    context = {"camera": camera, "visual": visual}
    session = PlaySession("Town1", 0, context=context, options=PlayOptions(n_traffic=2, draw=True))
    session.run(max_steps=2)
    view = session.view
    assert view.camera.name == camera and (view.fog is not None) == (visual == "foggy")
    assert view.limit_kmh == 50  # Town1's one-lane streets: 13.9 m/s
    image = _pixels(view.surface)
    ring = (np.abs(image.astype(int) - (210, 30, 30)).sum(-1) < 10)
    assert ring.sum() > 200  # the speed-limit sign's red ring


def test_default_view_is_the_simulated_drivers_camera():
    """Without --camera the person sees through the context's default camera (what the simulated driver assumes)."""
    from pernav.world.drivers import Context

    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, draw=True))
    session.run(max_steps=1)
    assert session.view.camera.name == Context().camera


def _off_road() -> FrameScript:
    """Full throttle with the wheel turned right for a second, then braking: the car ends up off the road."""
    return FrameScript(lambda frame: ControlInput(steer=0.6 if 30 < frame < 45 else 0.0, throttle=float(frame < 60),
                                                  brake=float(frame >= 60)))


def test_off_the_route_an_arrow_shows_the_way_back():
    session = PlaySession("Town1", 0, context={"camera": "third_person"}, controls=_off_road(),
                          options=PlayOptions(n_traffic=0, draw=True))
    session.run(max_steps=8)
    assert session.nav.world.ego.off_road
    view = session.view
    image = _pixels(view.surface)
    w = view.size[0]
    badge = image[w // 2 - 40: w // 2 + 40, 135 - 40: 135 + 40]  # the arrow's dark disc below the prompt
    assert _mask(badge, "route").sum() > 300


# ----- the truck's handling for a person ---------------------------------------------------------------------
class _Keys:
    """Throttle for two seconds, then the left key held for a second, then the brake: a person's keyboard."""

    keeps_lanes = False
    quit_requested = False

    def __init__(self) -> None:
        self.frames = 0
        self.log: list[tuple[float, float]] = []  # (steering angle, speed) after each frame's inputs

    def poll(self) -> None:
        pass

    def read(self, car):
        from pernav.world.controls import ControlInput

        self.frames += 1
        self.log.append((float(car.steer), float(car.speed)))
        if self.frames <= 20:
            return ControlInput(throttle=1.0, digital=True)
        if self.frames <= 30:
            return ControlInput(steer=-1.0, digital=True)
        return ControlInput(brake=1.0, digital=True)


def _drive_keys(vehicle: str) -> list[tuple[float, float]]:
    keys = _Keys()
    PlaySession("Town1", 0, controls=keys, context={"vehicle": vehicle}, options=PlayOptions(n_traffic=0)).run(max_steps=4)
    return keys.log


def test_the_truck_handles_differently_for_a_person():
    car, truck = _drive_keys("camaro"), _drive_keys("cybertruck")
    assert truck[20][1] < 0.8 * car[20][1]  # less acceleration (VehicleModel.accel_scale)
    assert abs(truck[24][0]) < 0.85 * abs(car[24][0])  # a slower wheel (the simulated driver's steering lag)
    assert min(car[35][1], truck[35][1]) > 0  # both still rolling: the speed lost is the deceleration
    lost_car, lost_truck = car[32][1] - car[35][1], truck[32][1] - truck[35][1]
    assert 0 < lost_truck < 0.8 * lost_car  # gentler braking (VehicleModel.max_decel)


def test_the_person_handling_leaves_simulated_drivers_alone():
    from pernav.env.navigation import NavigationEnv
    from pernav.play.handling import apply_handling
    from pernav.world.driver_car import DriverCar

    constants = (DriverCar.KEY_STEER_RATE, DriverCar.KEY_CENTRE_RATE, DriverCar.WHEEL_LAG)

    def simulated() -> tuple:
        env = NavigationEnv("Town1", config={"n_traffic": 2})
        _, info = env.reset(seed=0, options={"route": 0, "user": "user3", "context": {"vehicle": "cybertruck"}})
        for _ in range(40):
            _, _, done, cut, info = env.step(info["explore_action"])
            if done or cut:
                break
        return tuple(env.world.ego.position), env.tracking_cost

    before = simulated()
    session = PlaySession("Town1", 0, context={"vehicle": "cybertruck"}, options=PlayOptions(n_traffic=0))
    session.run(max_steps=1)
    assert session.nav.world.ego.KEY_STEER_RATE < DriverCar.KEY_STEER_RATE  # the person's truck only
    assert (DriverCar.KEY_STEER_RATE, DriverCar.KEY_CENTRE_RATE, DriverCar.WHEEL_LAG) == constants
    assert apply_handling(session.nav.world.ego) == 1.25
    assert simulated() == before


def test_bench_screenshots_option_is_checked_first(tmp_path, capsys):
    from pernav.cli import main

    assert main(["bench", "sim", "--screenshots", str(tmp_path)]) == 2  # only the play benchmark takes pictures
    assert main(["bench", "play", "--screenshots", str(tmp_path / "missing")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "--screenshots" in err
