"""The navigation's voice: one WAV per instruction and playback speed, and a speaker that plays them.

The files (``pernav/play/speech/{instruction}_{playback}.wav``, made by ``recipes/make_speech.py``) last
exactly ``audio_duration(instruction, playback)`` seconds, the time the simulated drivers take to hear the
instruction. Instruction 0 ("no instruction") is silence and has no file.

:class:`Speaker` plays through pygame's mixer when there is an audio device, and is silent otherwise (no
device, no pygame, ``SDL_AUDIODRIVER=dummy``): the prompt is then shown as text only, and nothing raises.

Example:
    >>> from pernav.play.audio import Speaker, speech_file, wav_duration
    >>> speech_file(3, "slower").name
    '3_slower.wav'
    >>> round(wav_duration(speech_file(3, "slower")), 2)  # 1.9 s x 1.3
    2.47
    >>> Speaker(enabled=False).say(1, "normal")
    False
"""

from __future__ import annotations

import contextlib
import operator
import os
import wave
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pernav.world.constants import ACTION_NAMES as INSTRUCTIONS  # light: loads neither highway-env nor pygame
from pernav.world.constants import PLAYBACK, Instruction

SPEECH_DIR = Path(__file__).resolve().parent / "speech"
RATE = 16_000  # Hz of the speech files: the mixer opens at it, so SDL need not resample them
NULL_DRIVERS = frozenset({"dummy", "disk"})  # SDL audio drivers that nobody hears: no device for a listener


def _instruction(instruction: Any, *, allow_silence: bool = False) -> int:
    try:
        if isinstance(instruction, bool):  # an int to Python, but surely a mistake here
            raise TypeError
        i = operator.index(instruction)  # ints and numpy integers, not 1.0 or "1"
    except TypeError:
        i = -1
    low = 0 if allow_silence else 1
    if not low <= i < len(INSTRUCTIONS):
        silence = "" if allow_silence else " (0, 'no instruction', is silence: no file)"
        raise ValueError(f"instruction {instruction!r} has no speech; allowed: {low}-{len(INSTRUCTIONS) - 1}{silence}")
    return i


def _playback(playback: Any) -> str:
    if playback not in PLAYBACK:
        raise ValueError(f"unknown playback {playback!r}; allowed: {', '.join(PLAYBACK)}")
    return playback


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Send file descriptor 2 to /dev/null for a moment: where there is no sound card, libasound writes a
    dozen lines of "ALSA lib ... cannot find card '0'" straight to it, below Python's reach (the reason
    still reaches the user, through ``Speaker.reason``)."""
    try:
        saved, null = os.dup(2), os.open(os.devnull, os.O_WRONLY)
    except OSError:  # no stderr to silence
        yield
        return
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def speech_file(instruction: int, playback: str = "normal", voice: str | os.PathLike[str] | None = None) -> Path:
    """The WAV file of an instruction (1-6) at a playback speed (``slower``, ``normal``, ``faster``); ``voice``: a
    folder of such files (the same names) instead of the built-in voice.

    >>> speech_file(1).name
    '1_normal.wav'
    >>> speech_file(0)
    Traceback (most recent call last):
    ValueError: instruction 0 has no speech; allowed: 1-6 (0, 'no instruction', is silence: no file)
    """
    return Path(voice or SPEECH_DIR) / f"{_instruction(instruction)}_{_playback(playback)}.wav"


def voice_missing(voice: str | os.PathLike[str]) -> list[str]:
    """The WAV files a voice folder lacks (every instruction 1-6 at every playback speed; ``[]``: complete).

    >>> voice_missing(SPEECH_DIR)
    []
    """
    return [p.name for p in (speech_file(i, pb, voice) for i in range(1, len(INSTRUCTIONS)) for pb in PLAYBACK)
            if not p.is_file()]


def wav_duration(path: str | os.PathLike[str]) -> float:
    """Seconds of sound in a WAV file (standard library only).

    >>> wav_duration(speech_file(5, "faster"))  # 1.6 s x 0.75
    1.2
    """
    with wave.open(str(path), "rb") as w:
        return w.getnframes() / w.getframerate()


class Speaker:
    """Plays the spoken prompts without blocking; silent (text only) where there is no audio device.

    ``Speaker()`` never raises: ``available`` says whether it will be heard and ``reason`` why not.
    ``Speaker.require()`` (or ``Speaker(require=True)``) raises ``RuntimeError("no audio device: ...")``
    instead, for a user who asked for sound explicitly.

    >>> speaker = Speaker(enabled=False)
    >>> speaker.available, speaker.reason
    (False, 'sound disabled')
    >>> speaker.say(2, "faster")
    False
    """

    def __init__(self, enabled: bool = True, *, require: bool = False) -> None:
        self.enabled = enabled
        self.volume = 1.0  # 0..1: the voice's volume (a lab's session file sets it)
        self.voice: Path | None = None  # a folder of the prompts' WAVs (None: the built-in voice)
        self.reason = "sound disabled"
        self._channel: Any = None  # pygame.mixer.Channel once a device is open
        self._sounds: dict[Path, Any] = {}
        self._owns_mixer = False
        if enabled or require:
            self._open()
        if require and not self.available:
            raise RuntimeError(f"no audio device: {self.reason}")

    @classmethod
    def require(cls) -> Speaker:
        """A speaker that will be heard, or ``RuntimeError("no audio device: ...")``."""
        return cls(enabled=True, require=True)

    @property
    def available(self) -> bool:
        """Whether an audio device plays what :meth:`say` says."""
        return self._channel is not None

    def _open(self) -> None:
        os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        try:
            import pygame  # lazy: importing this module must not load pygame
        except ImportError as exc:
            self.reason = f"pygame is not installed ({exc})"
            return
        try:
            if not pygame.mixer.get_init():
                with _quiet_stderr():
                    pygame.mixer.init(frequency=RATE, size=-16, channels=1, buffer=512)  # small buffer: prompt on time
                self._owns_mixer = True
            driver = pygame.mixer.get_driver()
            if driver in NULL_DRIVERS:
                self.reason = f"SDL audio driver {driver!r} plays to no device"
                self.close()
                return
            # One channel for the voice, reserved so that other sounds never take it: a new prompt cuts
            # the one still speaking, as a navigation voice does.
            pygame.mixer.set_reserved(1)
            self._channel = pygame.mixer.Channel(0)
            self.reason = ""
        except Exception as exc:  # pygame.error (no device, no driver) or anything odder: stay silent
            self.reason = f"{exc}".strip() or type(exc).__name__
            self.close()

    def say(self, instruction: int, playback: str = "normal") -> bool:
        """Start playing an instruction (0-6) and return at once: True if it is heard, False if silent.

        Instruction 0 is silence (False). A bad instruction or playback is a ValueError; a sound problem
        never raises (the prompt is then text only).
        """
        instruction, playback = _instruction(instruction, allow_silence=True), _playback(playback)
        if instruction == Instruction.NONE or self._channel is None:
            return False
        path = speech_file(instruction, playback, self.voice)
        try:
            sound = self._sounds.get(path)
            if sound is None:
                import pygame  # lazy: importing this module must not load pygame

                sound = self._sounds[path] = pygame.mixer.Sound(str(path))
            self._channel.set_volume(float(self.volume))
            self._channel.play(sound)
            return True
        except Exception as exc:  # a missing file, a device gone mid-run: this prompt stays text only
            self.reason = f"{exc}".strip() or type(exc).__name__
            return False

    def close(self) -> None:
        """Stop the voice and release the mixer if this speaker opened it."""
        channel, self._channel, self._sounds = self._channel, None, {}
        if channel is not None:
            try:
                channel.stop()
            except Exception:  # closing must not fail either
                pass
        if self._owns_mixer:
            self._owns_mixer = False
            try:
                import pygame  # lazy: importing this module must not load pygame

                pygame.mixer.quit()
            except Exception:  # closing must not fail either
                pass
