"""Spoken prompts: the WAV files, their lengths, the speaker without a device, and when the env plays one."""

from __future__ import annotations

import subprocess
import sys
import wave

import gymnasium as gym
import pytest

import pernav  # noqa: F401  (registers the ids)
from pernav.env.navigation import REPLAY_AFTER, NavigationEnv
from pernav.play import audio
from pernav.play.audio import Speaker, speech_file, wav_duration
from pernav.world.constants import ACTION_NAMES, PLAYBACK, audio_duration

SPOKEN = range(1, len(ACTION_NAMES))


def test_audio_reads_the_worlds_names():
    assert audio.INSTRUCTIONS == ACTION_NAMES and audio.PLAYBACK == PLAYBACK


@pytest.mark.parametrize("playback", PLAYBACK)
@pytest.mark.parametrize("instruction", SPOKEN)
def test_every_prompt_has_a_mono_16_bit_file_as_long_as_the_drivers_hear_it(instruction, playback):
    path = speech_file(instruction, playback)
    assert path.name == f"{instruction}_{playback}.wav" and path.is_file()
    with wave.open(str(path), "rb") as w:
        assert (w.getnchannels(), w.getsampwidth(), w.getframerate()) == (1, 2, audio.RATE)
        frames = w.readframes(w.getnframes())
    assert wav_duration(path) == pytest.approx(audio_duration(instruction, playback), abs=0.02)
    assert max(abs(int.from_bytes(frames[k:k + 2], "little", signed=True)) for k in range(0, len(frames), 2)) > 8000


def test_the_files_are_small_and_nothing_else_is_in_the_folder():
    files = sorted(audio.SPEECH_DIR.glob("*.wav"))
    assert [f.name for f in files] == sorted(f"{i}_{p}.wav" for i in SPOKEN for p in PLAYBACK)
    assert sum(f.stat().st_size for f in files) < 1_000_000


@pytest.mark.parametrize("instruction", [0, 7, -1, True, 1.0, "1", None])
def test_an_instruction_without_speech_is_a_value_error_naming_it_and_the_allowed_ones(instruction):
    with pytest.raises(ValueError, match=rf"instruction {instruction!r} has no speech; allowed: 1-6"):
        speech_file(instruction, "normal")


@pytest.mark.parametrize("playback", ["fast", "Normal", "", None, 1])
def test_an_unknown_playback_is_a_value_error_naming_it_and_the_allowed_ones(playback):
    message = f"unknown playback {playback!r}; allowed: slower, normal, faster"
    with pytest.raises(ValueError) as err:
        speech_file(1, playback)
    assert str(err.value) == message
    with pytest.raises(ValueError, match="unknown playback"):
        Speaker(enabled=False).say(1, playback)


def test_say_rejects_a_bad_instruction_even_when_silent_but_takes_zero_as_silence():
    speaker = Speaker(enabled=False)
    assert speaker.say(0, "normal") is False
    with pytest.raises(ValueError, match="instruction 7 has no speech; allowed: 0-6"):
        speaker.say(7, "normal")


def test_a_disabled_speaker_is_silent_and_opens_no_mixer():
    speaker = Speaker(enabled=False)
    assert not speaker.available and speaker.reason == "sound disabled"
    assert all(speaker.say(i, p) is False for i in SPOKEN for p in PLAYBACK)


def test_the_dummy_driver_is_no_device_the_speaker_stays_silent_and_require_says_why(monkeypatch):
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    speaker = Speaker()
    try:
        assert not speaker.available and "dummy" in speaker.reason
        assert all(speaker.say(i, p) is False for i in range(len(ACTION_NAMES)) for p in PLAYBACK)
    finally:
        speaker.close()
    for make in (Speaker.require, lambda: Speaker(require=True)):
        with pytest.raises(RuntimeError, match=r"^no audio device: SDL audio driver 'dummy' plays to no device$"):
            make()


def test_no_driver_at_all_is_silent_too(monkeypatch):
    monkeypatch.setenv("SDL_AUDIODRIVER", "no-such-driver")
    speaker = Speaker()
    try:
        assert not speaker.available and speaker.reason
        assert speaker.say(1, "normal") is False
    finally:
        speaker.close()
    with pytest.raises(RuntimeError, match="^no audio device: "):
        Speaker.require()


def test_with_a_device_say_plays_every_prompt_without_blocking(monkeypatch):
    # the dummy driver stands for a device here: the same pygame calls as on a machine with speakers
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    monkeypatch.setattr(audio, "NULL_DRIVERS", frozenset())
    speaker = Speaker.require()
    try:
        assert speaker.available and speaker.reason == ""
        heard = [speaker.say(i, p) for i in SPOKEN for p in PLAYBACK]
        assert heard == [True] * 18 and speaker.say(0, "normal") is False
        # started, not waited for: the last prompt (1.5 s of sound) is still playing when say has returned
        assert speaker.say(SPOKEN[-1], "slower") and speaker._channel.get_busy()
        # a file gone (a broken install) makes that prompt silent, not an error
        monkeypatch.setattr(audio, "SPEECH_DIR", audio.SPEECH_DIR / "missing")
        speaker._sounds.clear()
        assert speaker.say(1, "normal") is False and speaker.available
    finally:
        speaker.close()
    assert not speaker.available


def test_importing_the_audio_module_does_not_import_pygame():
    code = "import sys, pernav.play.audio, pernav.play; print('pygame' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _expected_played(instructions: list[int]) -> list[bool]:
    """The env's rule, written out: a prompt is played when it differs from the previous step's
    instruction, or when it has gone unplayed for REPLAY_AFTER steps; 0 is never played."""
    played, last, quiet = [], 0, 0
    for i in instructions:
        p = i != 0 and (i != last or quiet >= REPLAY_AFTER)
        played.append(p)
        quiet = 0 if p else quiet + 1
        last = i
    return played


def test_the_replay_rule_written_out():
    assert REPLAY_AFTER == 15
    # the same instruction every step: played at once, then again every REPLAY_AFTER + 1 steps
    assert [t for t, p in enumerate(_expected_played([1] * 40)) if p] == [0, 16, 32]
    # a change plays; a repeat does not; after a silent step the same instruction is new again
    assert _expected_played([0, 1, 1, 2, 2, 0, 2, 0, 0, 2, 3]) == [False, True, False, True, False, False,
                                                                     True, False, False, True, True]


SCRIPT = [1] * 20 + [2, 2, 1, 0, 1, 1, 0, 0, 3, 3] + [4] * 17 + [5, 6, 6]


def test_the_env_reports_played_exactly_per_the_rule():
    env = gym.make("pernav/Town1-v0", config={"n_traffic": 0})
    env.reset(seed=0, options={"route": 0})
    played = []
    for action in SCRIPT:
        _, _, terminated, truncated, info = env.step(action)
        played.append(info["played"])
        assert not (terminated or truncated)
    env.close()
    assert played == _expected_played(SCRIPT)
    assert [t for t, p in enumerate(played) if p] == [0, 16, 20, 22, 24, 28, 30, 46, 47, 48]


def test_with_adaptive_speed_a_new_playback_alone_does_not_replay():
    env = NavigationEnv("Town1", config={"n_traffic": 0, "adaptive_speed": True})
    env.reset(seed=0, options={"route": 0})
    script = [(1, "normal"), (1, "faster"), (1, "slower"), (2, "slower"), (2, "normal"), (0, "faster"), (2, "faster")]
    played = [env.step(env.encode(i, p))[4]["played"] for i, p in script]
    assert played == _expected_played([i for i, _ in script]) == [True, False, False, True, False, False, True]
