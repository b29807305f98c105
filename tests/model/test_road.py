"""A dynamics model that reads the road ahead (``DynamicsModel(road=n)``, ``TrainConfig.road``): the points it
reads on real drives and in imagination, its egocentric features, and that it learns what the state alone
cannot tell (where the road turns)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict

from pernav.model import DynamicsModel
from pernav.model.adapt import meta_parameters
from pernav.model.egocentric import ROAD_MAX, road_points
from pernav.model.losses import multistep_loss, single_step_loss
from pernav.model.navigation import ROUTE_REACH, ImaginedNavigationEnv, make_world_model, route_index
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.ftml import TrainConfig


@pytest.fixture(scope="module")
def drive():
    from pernav.env.torchrl_env import explore_module
    from pernav.trainer.collect import drive, history_env

    return drive(history_env("Town3", {"route": 0}, config={"n_traffic": 2}, seed=0, K=5), explore_module())


@pytest.mark.slow
def test_road_points_on_a_drive_start_at_the_car_and_match_the_imagined_projection(drive):
    road = road_points(drive["route_ahead"])  # what the buffers store
    assert road.shape == (drive.shape[0], ROAD_MAX, 2)
    gaps = (road[:, 1:] - road[:, :-1]).norm(dim=-1)
    # 6 m apart along the route (route_ahead snaps its 3-m points to the route's 2-m waypoints: 4 to 8 m)
    assert float(gaps.max()) <= 8.0 + 1e-3 and float(gaps[gaps > 0].median()) == pytest.approx(6.0, abs=0.1)
    here = (road[:, 0] - drive["observation"][:, :2]).norm(dim=-1)
    assert float(here.median()) < 2.0  # the first point is the car's projection on the route
    # imagination finds the projection itself (nearest route point); the same road within a point's spacing
    off = []
    for t in range(drive.shape[0]):
        route = drive[t]["route_ahead"]
        index = torch.cdist(drive[t]["observation"][:2].unsqueeze(0), route).argmin()
        off.append(float((road_points(route, ROAD_MAX, index) - road[t]).norm(dim=-1).max()))
    assert float(torch.tensor(off).median()) < 3.0 + 1e-3


def _state(x: float, y: float, heading: float, speed: float = 8.0) -> torch.Tensor:
    s = torch.zeros(14)
    s[0], s[1], s[3], s[4], s[6] = x, y, speed * math.cos(heading), speed * math.sin(heading), heading
    s[9], s[10] = x + 20 * math.cos(heading), y + 20 * math.sin(heading)
    return s


def _moved(v: torch.Tensor, angle: float, shift: torch.Tensor, point: bool = True) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    out = torch.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], -1)
    return out + shift if point else out


def test_the_road_is_read_in_the_cars_frame_so_a_rigid_motion_of_the_world_changes_nothing():
    torch.manual_seed(0)
    model = DynamicsModel(hidden=(16,), road=4)
    g = torch.Generator().manual_seed(1)
    history = torch.randn(3, 5, 21, generator=g) * 5
    road = torch.randn(3, 4, 2, generator=g) * 20
    action = torch.tensor([0, 2, 5])
    angle, shift = 1.1, torch.tensor([30.0, -12.0])
    moved = history.clone()
    for a, b, point in ((0, 1, True), (3, 4, False), (9, 10, True)):  # positions, velocities, goals
        moved[..., [a, b]] = _moved(history[..., [a, b]], angle, shift, point)
    moved[..., 6] = history[..., 6] + angle
    window, moved_window = model.with_action(history, action), model.with_action(moved, action)
    torch.testing.assert_close(model.delta(window, road), model.delta(moved_window, _moved(road, angle, shift)),
                               rtol=1e-4, atol=1e-4)
    assert not torch.allclose(model.delta(window, road), model.delta(window, road.flip(-2)))  # it reads the road


def test_a_model_needs_its_road_and_the_option_is_bounded(tmp_path, capsys):
    from pernav.cli import main

    model = DynamicsModel(hidden=(8,), road=4)
    with pytest.raises(ValueError, match="reads 4 road points"):
        model(torch.zeros(2, 5, 21), torch.zeros(2, dtype=torch.long))
    with pytest.raises(ValueError, match="road must be between 0 and 16"):
        DynamicsModel(road=ROAD_MAX + 1)
    assert TrainConfig().with_options(["road=8"]).road == 8 and TrainConfig().road == 0
    assert DynamicsModel(**model.config()).road == 4  # checkpoints rebuild it
    assert main(["study", "--preset", "smoke", "--out", str(tmp_path / "s"), "--train-option", "road=17"]) == 2
    err = capsys.readouterr().err
    assert "road=17" in err and "an int from 0 to 16" in err and not (tmp_path / "s").exists()


def _turns(n: int, seed: int) -> TensorDict:
    """Cars at random poses on a road that bends left or right 12 m ahead; the next second the car turns
    with the road. The state alone says nothing about the bend; the road does."""
    g = torch.Generator().manual_seed(seed)
    rows = []
    for _ in range(n):
        x, y, h = (torch.rand(3, generator=g) * torch.tensor([100.0, 100.0, 6.28])).tolist()
        bend = 0.5 if torch.rand(1, generator=g) < 0.5 else -0.5
        now, nxt = _state(x, y, h), _state(x + 8 * math.cos(h + bend / 2), y + 8 * math.sin(h + bend / 2), h + bend)
        along = torch.arange(4.0) * 6
        local = torch.stack([along.clamp(max=12) + (along - 12).clamp(min=0) * math.cos(bend),
                             (along - 12).clamp(min=0) * math.sin(bend)], -1)
        history = torch.zeros(5, 21)
        history[:, :14] = now
        rows.append({"observation": now, "next": {"observation": nxt}, "history": history,
                     "action": torch.tensor(0), "road": _moved(local, h, torch.tensor([x, y]))})
    return torch.stack([TensorDict(r, []) for r in rows])


@pytest.mark.slow
def test_a_model_that_reads_the_road_learns_where_the_car_turns_and_one_without_cannot():
    train, held = _turns(256, 0).unsqueeze(1), _turns(128, 1).unsqueeze(1)  # [B, 1] one-step windows
    losses = {}
    for road in (0, 4):
        torch.manual_seed(0)
        model = DynamicsModel(hidden=(64, 64), road=road)
        data = train.squeeze(1)
        model.fit_normalization(data["history"], data["action"], data["next", "observation"], data["road"])
        opt = torch.optim.Adam(model.parameters(), lr=3e-3)
        for _ in range(300):
            opt.zero_grad()
            single_step_loss(model, train).backward()
            opt.step()
        with torch.no_grad():
            losses[road] = float(single_step_loss(model, held))
    assert losses[4] < 0.3 * losses[0], losses


def test_buffers_keep_the_road_and_an_ensembles_batched_loss_reads_it(drive):
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, drive, tau=True)
    stored = buffers.data(0)
    torch.testing.assert_close(stored["road"], road_points(drive["route_ahead"]))
    assert "road" in RoundBuffers.of([buffers.tau(0)], L=3).data(0).keys()  # stored data re-added keeps it
    torch.manual_seed(0)
    models = [DynamicsModel(hidden=(16,), road=6) for _ in range(2)]
    for m in models:
        m.fit_normalization(stored["history"], stored["action"], stored["next", "observation"], stored["road"])
    batch = buffers.sample(0, 8)
    params = [meta_parameters(m).detach() for m in models]
    both = multistep_loss(models[0], batch, params=torch.stack(params))
    for i, p in enumerate(params):
        torch.testing.assert_close(both[i], multistep_loss(models[0], batch, params=p), rtol=1e-5, atol=1e-5)


def test_imagination_gives_the_road_at_each_imagined_cars_projection(drive):
    torch.manual_seed(0)
    model = DynamicsModel(hidden=(16,), road=5)
    env = ImaginedNavigationEnv(make_world_model(model))
    root = drive[10]
    seqs = torch.randint(7, (3, 6))
    pos, _ = env.imagine(root, seqs)
    # brute force: one sequence at a time, tracking the car's projection on the route
    route = root["route_ahead"]
    for n in range(3):
        hist = root["history"].clone()
        index = torch.cdist(hist[-1, :2].unsqueeze(0), route).argmin()
        for h in range(6):
            state = model(hist, seqs[n, h], road_points(route, 5, index))
            index = route_index(state, route, index)
            hist = model.next_window(hist, seqs[n, h], state)
            torch.testing.assert_close(pos[0, n, h], state[:2], rtol=1e-5, atol=1e-4)


def test_adapting_on_a_raw_drive_reads_its_route_and_the_paper_planner_plans_with_the_road(drive):
    from pernav.model.adapt import adapt
    from pernav.planner.tree_search import TreeSearchPlanner

    torch.manual_seed(0)
    model = DynamicsModel(K=5, hidden=(16,), road=4)
    stored = RoundBuffers.of([drive], L=3).data(0)
    model.fit_normalization(stored["history"], stored["action"], stored["next", "observation"], stored["road"])
    raw = drive[:20]  # as the env gives it: route_ahead, no stored road
    windows = raw[torch.arange(16).unsqueeze(1) + torch.arange(3)]
    torch.testing.assert_close(multistep_loss(model, windows), multistep_loss(model, stored[:20][
        torch.arange(16).unsqueeze(1) + torch.arange(3)]))
    adapted = adapt(model, raw, alpha=0.01, L=3, first_order=True)
    assert multistep_loss(model, windows, params=adapted) < multistep_loss(model, windows)
    planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)), horizon=3)
    assert "route_ahead" in planner.in_keys
    out = planner(drive[12].select(*planner.in_keys).clone())
    assert bool(drive[12]["action_mask"][0, out["action"]])  # a masked-tree choice, planned on the road
    with pytest.raises(KeyError, match="route_ahead"):
        planner(drive[12].exclude("route_ahead"))


def test_the_route_projection_is_the_nearest_point_near_the_previous_one():
    g = torch.Generator().manual_seed(0)
    route = torch.cumsum(torch.randn(40, 2, generator=g) * 3, 0)
    state = torch.zeros(200, 14)
    state[:, :2] = route[torch.randint(40, (200,), generator=g)] + torch.randn(200, 2, generator=g) * 4
    index = torch.randint(40, (200,), generator=g)
    new = route_index(state, route, index)
    d = torch.cdist(state[:, :2], route)  # brute force: every point, masked to the reachable ones
    k = torch.arange(40)
    reach = (k >= index.unsqueeze(-1) - 2) & (k <= index.unsqueeze(-1) + ROUTE_REACH)
    assert torch.equal(new, torch.where(reach, d, torch.full_like(d, float("inf"))).argmin(-1))


def test_speed_actions_keep_the_road_and_a_beam_needs_a_model_without_it(drive):
    from pernav.planner.tree_search import TreeSearchPlanner
    from pernav.trainer.collect import to_speed_actions

    wide = to_speed_actions(drive)
    torch.testing.assert_close(wide["road"], road_points(drive["route_ahead"]))  # adapt_speed's data too
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(n_actions=21, hidden=(8,), road=4)))
    with pytest.raises(ValueError, match="beam search needs a model without the road"):
        TreeSearchPlanner(env, beam=64)


def test_a_drive_goes_into_a_models_action_space_once(drive):
    from pernav.trainer.collect import in_action_space, to_speed_actions

    wide = in_action_space(drive, 21)  # the study's learners and a person's session re-encode by this one rule
    assert torch.equal(wide["history"], to_speed_actions(drive)["history"])
    assert torch.equal(wide["action"].reshape(-1), drive["action"].long().reshape(-1) * 3 + 1)
    assert in_action_space(wide, 21) is wide and in_action_space(drive, 7) is drive  # already there: as it is


def test_a_study_refuses_the_road_with_the_paper_planners_beam_before_writing_anything(tmp_path, capsys):
    from pernav.cli import main

    out = tmp_path / "s"
    args = ["study", "--preset", "smoke", "--out", str(out), "--planner", "paper", "--train-option", "road=4"]
    assert main([*args, "--methods", "explore", "adapt_speed"]) == 2
    err = capsys.readouterr().err
    assert "adapt_speed" in err and "road" in err and "Traceback" not in err and not out.exists()
