"""``pernav bench play --live`` (:mod:`pernav.play.livebench`): the play loop in a window paced to real time."""

from __future__ import annotations

import os

import pytest

pytest.importorskip("pygame")


def test_a_live_view_without_a_display_says_it_is_the_dummy_driver(monkeypatch):
    """No DISPLAY, WAYLAND_DISPLAY nor SDL_VIDEODRIVER: SDL's dummy driver, said plainly, set for the benchmark only;
    one second of Town1 (10 world frames) paced to the clock."""
    from pernav.play.livebench import bench_live, live_view

    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    d = live_view("top", steps=1, town="Town1", route=0, n_traffic=0)
    assert "SDL_VIDEODRIVER" not in os.environ
    assert d["display"] == "dummy" and d["world_frames"] == 10 and d["stalls"] == 0
    assert 0 < d["frame_ms_median"] <= d["frame_ms_p95"] and 0 <= d["late_ms_median"] <= d["late_ms_p95"]
    assert 0 <= d["pictures_skipped"] < 30

    monkeypatch.setattr("pernav.play.livebench.live_view", lambda camera, visual, steps, screenshot: {**d, "shot": None})
    out = bench_live([("top", "normal"), ("first_person", "foggy")], steps=1)
    assert out["display"] == "dummy" and not out["real_window"]
    assert "dummy" in out["note"] and "real window" in out["note"]
    assert out["first_person_fog_frame_ms_p95"] == d["frame_ms_p95"] and "top_late_ms_p95" in out
    assert out["all_views_meet_target"] == (d["frame_ms_p95"] <= 50.0) == out["top_meets_target"]


def test_bench_play_passes_live_through(monkeypatch):
    """``run_benchmarks("play", live=True)`` runs each view live (5 s each when quick); without it, off screen."""
    from pernav.cli import bench

    calls = []
    monkeypatch.setattr(bench, "bench_live",  # the benchmarks' own name for it
                        lambda views, steps, screenshots: calls.append((list(views), steps)) or {"live": True})
    assert bench.run_benchmarks("play", quick=True, live=True) == {"play": {"live": True}}
    assert calls == [(list(bench.PLAY_VIEWS), 5)]
