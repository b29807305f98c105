"""Make the navigation's spoken prompts: one small WAV per instruction and playback speed.

Not an example to copy: the generator of the speech files committed in ``pernav/play/speech/``; run it only to
re-make them (a few seconds with a speech engine installed).

Writes ``{instruction}_{playback}.wav`` for instructions 1-6 (0, "no instruction", is silence: no file) and
the playback speeds of :data:`pernav.world.constants.PLAYBACK`, as 16-bit mono PCM at 16 kHz, into the
folder given (the package's copy is ``pernav/play/speech``, committed: the package never needs a speech
engine at run time).

Engines, tried in this order (the first that speaks is used, and printed):

1. an ``espeak-ng`` or ``espeak`` binary on the PATH;
2. the PyPI wheel ``espeakng-loader`` (``.venv/bin/pip install espeakng-loader``), which ships libespeak-ng
   and its voice data: driven through ctypes, no system package needed;
3. ``pyttsx3`` (on Linux it needs a system libespeak, so it rarely gets further than 1);
4. fallback, not speech: a tone pattern per instruction (1-2 beeps, low for left, high for right, a rising
   pair for the roundabout). Used only when none of the above works; the script then says so loudly.

The committed files were made with engine 2 (espeakng-loader 0.2.4, espeak-ng voice ``en-us``).

How each file gets its exact length (the simulated drivers hear an instruction for
``audio_duration(instruction, playback)`` seconds, so the sound must last exactly that long):

* normal: spoken at a steady 150 words a minute (slower than espeak's 175: a navigation voice is paced for a
  driver); leading and trailing silence is trimmed, the speech starts after a 60 ms lead-in and is padded
  with silence to exactly ``AUDIO_DURATION[i]`` (every phrase fits: 0.7-1.4 s of speech in 1.2-1.9 s). Were a
  phrase too long, it would be re-spoken faster until it fits, and as a last resort cut with a short fade.
* slower / faster: the same phrase re-spoken at 150 / 1.3 and 150 / 0.75 words a minute: the engine's own
  time-stretch, which keeps the pitch (resampling the normal file would make "faster" squeak and "slower"
  growl). The speech then lasts about 1.3x / 0.75x the normal speech, and the lead-in and padding are scaled
  likewise to exactly ``audio_duration(i, playback)``.
* the engine's 22.05 kHz output is resampled to 16 kHz (band-limited, FFT) and each file is normalised to a
  peak of -3 dBFS, so all prompts are equally loud. 16 kHz mono 16-bit is the smallest format allowed:
  the 18 files hold 27.45 s of sound, about 0.88 MB (mostly silence, which git compresses well).

Re-running gives the same bytes (espeak-ng is deterministic).

Run: .venv/bin/python recipes/make_speech.py pernav/play/speech
"""

from __future__ import annotations

import argparse
import ctypes
import shutil
import subprocess
import sys
import tempfile
import wave
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

import numpy as np

from pernav.world.constants import ACTION_NAMES, PLAYBACK, PLAYBACK_SCALE, audio_duration

RATE = 16_000  # Hz of the written files
WPM = 150  # words a minute at normal playback
LEAD_IN = 0.06  # s of silence before the speech at normal playback
PEAK = 10 ** (-3 / 20)  # -3 dBFS
FADE = 0.005  # s of fade at a cut (no click)

# an engine: (instruction, text, words a minute) -> (samples in [-1, 1], sample rate)
Engine = Callable[[int, str, float], tuple[np.ndarray, int]]


def read_wav(path: Path) -> tuple[np.ndarray, int]:
    with wave.open(str(path), "rb") as w:
        if w.getsampwidth() != 2:
            raise ValueError(f"{path}: expected 16-bit samples, got {8 * w.getsampwidth()}-bit")
        x = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2").astype(np.float64) / 32768.0
        return x.reshape(-1, w.getnchannels()).mean(axis=1), w.getframerate()


def write_wav(path: Path, x: np.ndarray, rate: int = RATE) -> None:
    pcm = np.clip(np.round(x * 32767.0), -32768, 32767).astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(pcm.tobytes())


# ----- engines ------------------------------------------------------------------------------------

def binary_engine() -> tuple[str, Engine] | None:
    exe = shutil.which("espeak-ng") or shutil.which("espeak")
    if exe is None:
        return None

    def speak(instruction: int, text: str, wpm: float) -> tuple[np.ndarray, int]:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "x.wav"
            subprocess.run([exe, "-v", "en-us", "-s", str(round(wpm)), "-w", str(out), text], check=True,
                           capture_output=True)
            return read_wav(out)

    return f"{Path(exe).name} binary ({exe})", speak


def loader_engine() -> tuple[str, Engine] | None:
    try:
        import espeakng_loader
    except ImportError:
        return None
    lib = ctypes.CDLL(espeakng_loader.get_library_path())
    callback_type = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.c_void_p)
    chunks: list[np.ndarray] = []

    def on_audio(wav, n, events) -> int:  # espeak hands the audio over in chunks, during espeak_Synth
        if wav and n > 0:
            chunks.append(np.ctypeslib.as_array(wav, shape=(n,)).copy())
        return 0  # 0: go on

    keep = callback_type(on_audio)  # referenced by the closure below: ctypes must not free it
    lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    lib.espeak_SetParameter.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int]
    lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
    lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int, ctypes.c_uint,
                                 ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    # AUDIO_OUTPUT_SYNCHRONOUS (2): no audio device, the samples come back through the callback
    rate = lib.espeak_Initialize(2, 0, espeakng_loader.get_data_path().encode(), 0)
    if rate <= 0 or lib.espeak_SetVoiceByName(b"en-us") != 0:
        return None
    lib.espeak_SetSynthCallback(keep)

    def speak(instruction: int, text: str, wpm: float) -> tuple[np.ndarray, int]:
        chunks.clear()
        lib.espeak_SetParameter(1, round(wpm), 0)  # espeakRATE, absolute
        data = text.encode()
        # position 0 (POS_CHARACTER), flags espeakCHARS_UTF8 (1)
        if lib.espeak_Synth(data, len(data) + 1, 0, 0, 0, 1, None, None) != 0:
            raise RuntimeError(f"espeak_Synth failed on {text!r}")
        lib.espeak_Synchronize()
        _ = keep
        return np.concatenate(chunks).astype(np.float64) / 32768.0, rate

    return f"espeakng-loader {metadata.version('espeakng-loader')} (libespeak-ng via ctypes, voice en-us)", speak


def pyttsx3_engine() -> tuple[str, Engine] | None:
    try:
        import pyttsx3

        tts = pyttsx3.init()
    except Exception:  # no module, or no driver underneath it
        return None

    def speak(instruction: int, text: str, wpm: float) -> tuple[np.ndarray, int]:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "x.wav"
            tts.setProperty("rate", round(wpm))
            tts.save_to_file(text, str(out))
            tts.runAndWait()
            return read_wav(out)

    return "pyttsx3", speak


# fallback (not speech): (tone Hz, tone s, gap s) per instruction, at normal pace
TONES = {
    1: [(440, 0.25, 0.0)],  # turn left: one low beep
    2: [(880, 0.25, 0.0)],  # turn right: one high beep
    3: [(440, 0.15, 0.1), (440, 0.15, 0.0)],  # prepare left: two low
    4: [(880, 0.15, 0.1), (880, 0.15, 0.0)],  # prepare right: two high
    5: [(440, 0.15, 0.1), (660, 0.15, 0.1), (880, 0.15, 0.0)],  # roundabout: rising three
    6: [(660, 0.12, 0.08), (440, 0.25, 0.0)],  # keep left: mid then low
}


def tone_engine(instruction: int, text: str, wpm: float) -> tuple[np.ndarray, int]:
    scale, parts = WPM / wpm, []
    for hz, on, gap in TONES[instruction]:
        t = np.arange(round(on * scale * RATE)) / RATE
        envelope = np.minimum(1.0, np.minimum(t, t[-1] - t) / 0.01)  # 10 ms ramps: no clicks
        parts += [0.5 * np.sin(2 * np.pi * hz * t) * envelope, np.zeros(round(gap * scale * RATE))]
    return np.concatenate(parts), RATE


def pick_engine() -> tuple[str, Engine, bool]:
    """(name, engine, is speech) of the first engine that speaks."""
    for make in (binary_engine, loader_engine, pyttsx3_engine):
        try:
            found = make()
            if found is not None:
                name, speak = found
                if np.abs(speak(1, ACTION_NAMES[1], WPM)[0]).max() > 0.01:  # it said something
                    return name, speak, True
        except Exception as exc:  # a broken install: try the next one
            print(f"{make.__name__}: {type(exc).__name__}: {exc}", file=sys.stderr)
    return "tone fallback (no speech engine found)", tone_engine, False


# ----- fitting ------------------------------------------------------------------------------------

def resample(x: np.ndarray, rate: int, to: int = RATE) -> np.ndarray:
    """Band-limited resampling by FFT (no scipy in the project): keep the spectrum below the new Nyquist."""
    if rate == to:
        return x
    n = len(x)
    m = round(n * to / rate)
    spectrum = np.fft.rfft(x)[: m // 2 + 1]
    return np.fft.irfft(spectrum, m) * (m / n)


def trim(x: np.ndarray, rate: int) -> np.ndarray:
    """Cut leading and trailing silence (below 2 % of the peak), keeping 10 ms either side."""
    loud = np.nonzero(np.abs(x) > 0.02 * np.abs(x).max())[0]
    keep = round(0.01 * rate)
    return x[max(loud[0] - keep, 0): loud[-1] + keep + 1]


def fit(speech: np.ndarray, duration: float, lead_in: float) -> np.ndarray:
    """``speech`` after ``lead_in`` s of silence, padded with silence (or cut with a fade) to ``duration`` s."""
    total, lead = round(duration * RATE), round(lead_in * RATE)
    room = total - lead
    if len(speech) > room:
        speech = speech[:room].copy()
        n = round(FADE * RATE)
        speech[-n:] *= np.linspace(1.0, 0.0, n)
    out = np.zeros(total)
    out[lead: lead + len(speech)] = speech
    return out


def spoken(speak: Engine, instruction: int, playback: str) -> np.ndarray:
    """The instruction at a playback speed, exactly ``audio_duration(instruction, playback)`` long."""
    scale = PLAYBACK_SCALE[playback]
    duration, lead_in = audio_duration(instruction, playback), LEAD_IN * scale
    wpm = WPM / scale
    for _ in range(12):  # speak faster until it fits (never needed for the built-in phrases)
        x, rate = speak(instruction, ACTION_NAMES[instruction], wpm)
        speech = resample(trim(x, rate), rate)
        if len(speech) <= round((duration - lead_in) * RATE) or wpm >= 400:
            break
        wpm *= 1.1
    speech = speech * (PEAK / np.abs(speech).max())
    return fit(speech, duration, lead_in)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder for the WAV files (pernav/play/speech)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    name, speak, is_speech = pick_engine()
    print(f"engine: {name}")
    if not is_speech:
        print("WARNING: no speech engine: writing tone patterns instead of speech (see this script's docstring)")
    size = 0
    for instruction in range(1, len(ACTION_NAMES)):
        for playback in PLAYBACK:
            path = args.out / f"{instruction}_{playback}.wav"
            x = spoken(speak, instruction, playback)
            write_wav(path, x)
            size += path.stat().st_size
            print(f"{path}  {len(x) / RATE:.3f} s  {ACTION_NAMES[instruction]!r} ({playback})")
    print(f"{len(ACTION_NAMES) - 1} instructions x {len(PLAYBACK)} speeds, {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
