"""What a participant sees around and during the drives of a session: the prompt held until its junction, the drive
counter on the HUD, one window across drives, the waiting and end screens between and after them.

Headless: views draw off screen (or into SDL's dummy window); the scripted bot drives; no pixels compared.
"""

from __future__ import annotations

import copy
import os

import pytest

from pernav.play.controls import ScriptedControls, SessionKeys
from pernav.play.loop import PlaySession
from pernav.play.options import PlayOptions
from pernav.world.constants import ACTION_NAMES, audio_duration
from pernav.world.controls import ControlInput

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # windows drawn off screen
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

pygame = pytest.importorskip("pygame")

from pernav.play.screens import (  # noqa: E402
    FINISHED,
    STOPPED,
    SessionWindow,
    show_finished,
    show_waiting,
    time_left,
    wait_for_go,
)
from pernav.play.view import PlayView, hud_texts  # noqa: E402
from pernav.world.towns import get_town  # noqa: E402


class Halting(ScriptedControls):
    """The bot, but standing on the brake from frame 60 to 250 (stopped well before the first junction); every
    frame it notes the prompt on screen and where the car is."""

    def __init__(self, session: PlaySession) -> None:
        super().__init__()
        self.session, self.seen = session, []

    def read(self, car):
        control = super().read(car)
        return ControlInput(brake=1.0, digital=True) if 60 <= self.frames < 250 else control

    def poll(self) -> None:
        s = self.session
        self.seen.append((s.nav.world.time, s.prompt, s.prompt_text(), s.route_progress, s.nav.reroutes))


def test_a_prompt_holds_until_its_junction_is_passed():
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, seed=0))
    junction = session.nav.route.upcoming(0.0)[0].s
    session.controls = bot = Halting(session)
    session.run(max_steps=50)
    held = [row for row in bot.seen if 20.0 <= row[0] <= 24.0]  # standing still before the junction
    prompt = held[0][1]
    assert prompt is not None and all(row[1] is prompt and row[3] < junction for row in held)
    instruction, playback, at = prompt
    ahead = [row for row in bot.seen if row[1] is prompt and row[4] == 0 and row[3] < junction]
    late = [row for row in ahead if row[0] > at + audio_duration(instruction, playback) + 10]
    assert len(late) > 50  # seconds after its audio, the junction still ahead: still on screen
    assert all(text.startswith(f"{ACTION_NAMES[instruction]}  -  ") for _, _, text, _, _ in late)
    assert len({text for _, _, text, _, _ in late}) > 1  # with the live distance
    # past its junction (turned there, or gone on and re-routed: the old route's junction is behind either way)
    passing = next(t for t, _, _, progress, reroutes in bot.seen if progress >= junction or reroutes > 0)
    after = [row for row in bot.seen if row[0] >= passing and row[1] is prompt]
    assert after and all(text is None for _, _, text, _, _ in after)  # gone once the car is past its junction


def test_a_re_route_drops_the_prompt_and_one_with_nothing_ahead_stays_a_while():
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, seed=0))
    session.env.reset()
    nav = session.nav
    session.prompt = (1, "normal", nav.world.time - 30.0)  # long ago, the junction still ahead
    assert session.prompt_text().startswith("turn left  -  ")
    nav.route = copy.copy(nav.route)  # what a re-plan does: another route (here the same way)
    assert session.prompt_text() is None
    end = nav.route.length - 4.0  # past the last manoeuvre: the old rule, 5 s after the audio
    nav.world.ego.position, nav.progress = nav.route.point_at(end).copy(), end
    session.prompt = (1, "normal", nav.world.time)
    assert session.prompt_text() == "turn left"
    session.prompt = (1, "normal", nav.world.time - 7.0)
    assert session.prompt_text() is None


def test_the_hud_shows_the_drive_counter_and_hides_the_cost():
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, draw=True, title="Drive 2 of 6: Town1 route 0",
                                                          progress="Drive 2 of 6", hide_cost=True))
    session.run(max_steps=2)
    texts = hud_texts(session)
    assert texts["drive"] == "Drive 2 of 6" and "cost" not in texts["status"]
    titled = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, title="Town1 route 0"))
    assert hud_texts(titled)["drive"] == "Town1 route 0"
    assert "drive" not in hud_texts(PlaySession("Town1", 0, options=PlayOptions(n_traffic=0)))


class Speaker:
    closed = 0

    def say(self, instruction: int, playback: str) -> bool:
        return False

    def close(self) -> None:
        self.closed += 1


def test_a_session_given_a_window_draws_into_it_and_leaves_it_open():
    view = PlayView(get_town("Town1"), size=(480, 360), window=True)
    speaker = Speaker()
    first = PlaySession("Town1", 0, speaker=speaker, view=view, context={"camera": "top"}, options=PlayOptions(n_traffic=0))
    assert first.view is view
    first.run(max_steps=2)
    first.close()
    assert pygame.display.get_init() and pygame.display.get_surface() is view.surface and speaker.closed == 0
    assert view.camera_name == "top"
    second = PlaySession("Town2", 1, view=view, context={"camera": "first_person"}, options=PlayOptions(n_traffic=0))
    second.run(max_steps=2)  # the window shows the second drive's town and camera
    assert view.town is second.nav.town and view.camera_name == "first_person"
    view.close()
    assert not pygame.display.get_init()
    alone = PlaySession("Town1", 0, speaker=speaker, options=PlayOptions(n_traffic=0, window=True, realtime=False))
    alone.close()  # its own window and the speaker, as before
    assert not pygame.display.get_init() and speaker.closed == 1


class GoAfter(SessionKeys):
    """Keys whose go comes at the ``n``-th poll (or Esc, with ``key="escape"``)."""

    def __init__(self, n: int, key: str = "go") -> None:
        self.n, self.key, self.polls = n, key, 0

    def poll(self) -> None:
        self.polls += 1
        if self.polls == self.n:
            self.press(self.key)


def test_waiting_and_finished_screens_draw_and_the_end_waits_for_go():
    view = PlayView(get_town("Town1"), size=(480, 360))
    show_waiting(view, "the navigation is learning from your drives", 35.0, title="Drive 2 of 3")
    show_waiting(view, "setting up", None)
    assert time_left(34.0) == "about 35 s left" and time_left(-1.0) == "almost done"
    drawn = []
    keys = GoAfter(4)
    keys.quit_requested = True  # the quit that ended the last drive does not close the end screen
    assert wait_for_go(keys, lambda: drawn.append(1), hz=1000) and keys.polls == 4 and len(drawn) == 4
    assert not wait_for_go(GoAfter(2, key="escape"), hz=1000)  # Esc (or the close button) leaves it too
    assert show_finished(view, ["You drove all 3 drives."], controls=ScriptedControls())
    assert show_finished(view, ["You drove all 3 drives."])  # no controls: drawn once


def test_the_waiting_screen_answers_the_window_but_keeps_its_close_button():
    view = PlayView(get_town("Town1"), size=(480, 360), window=True)
    try:
        pygame.event.clear()
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN, unicode="\r"))
        pygame.event.post(pygame.event.Event(pygame.QUIT))
        show_waiting(view, "the navigation is learning from your drives", 12.0)
        assert [e.type for e in pygame.event.get()] == [pygame.QUIT]  # an Enter while waiting starts nothing
    finally:
        view.close()


def test_a_session_window_headless_draws_nothing():
    made = []
    with SessionWindow("Town1", window=False) as screens:
        screens.waiting("setting up", 3.0)
        screens.learning("learning", 0.0, 5.0)
        assert not screens.finish(lambda: made.append(1), 1, 3, stopped=True)
    assert screens.view is None and made == []  # no controls made: there is no screen to leave


def test_a_session_window_ends_with_the_session_screen(monkeypatch):
    import pernav.play.screens as screens_module

    panels: list[list[str]] = []
    panel = screens_module.show_panel
    monkeypatch.setattr(screens_module, "show_panel", lambda view, lines, **kw: panels.append(list(lines))
                        or panel(view, lines, **kw))
    with SessionWindow("Town1", window=True) as screens:
        assert screens.view.window
        screens.learning("the navigation is learning from your drives", 0.0, 1e9, last=True)
        assert not screens.finish(ScriptedControls, 2, 3, stopped=True)
    assert screens.view is None and not pygame.display.get_init()
    assert panels[0][0] == "Finishing the session" and panels[0][1].endswith("min left")
    assert panels[-1][:2] == [STOPPED, "2 of 3 drives driven; what you drove is kept."] and STOPPED != FINISHED
