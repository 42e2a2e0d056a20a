"""Sounds that are not speech, made up from a seed: what the voice detector learns to leave alone.

A puppet must rest its mouth through a music intro, a keyboard's clatter or a fan, yet the
landmark network, trained on speech alone, moves the mouth for any loud sound (on instrumental
music it opened the lips as far as on speech). `sound(seconds, rng)` draws one clip of one kind:

  music:   a chord progression (2–4 note chords of one key, 60–160 bpm) over a bass line, with a
           melody, with or without drums. Where fluidsynth and a General MIDI soundfont are installed
           (Debian: fluidsynth, fluid-soundfont-gm), most clips are that music written as MIDI and
           played by sampled instruments (any of the 128 GM programs, the GM drum kit): real timbres.
           Otherwise (and in the rest), each part is synthesised here: plucked (Karplus–Strong
           string), struck (decaying partials, harmonic or bell-like inharmonic) or bowed/blown
           (slow attack, vibrato), drums a pitch-swept kick, a noise snare and a hi-hat;
  tones:   beeps, whistles, sirens and chimes: one or two partials gliding or stepping;
  noise:   white, pink or brown noise, through a random band-pass, swelling and fading; mains hum;
  knocks:  clicks, taps, claps and typing: short noise or resonant bursts at random times.

Every clip is (N,) float32 at RATE (16 kHz) with its peak at full scale 0.5; callers set the level.
"""
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from scipy import signal

from puppet import audio
from puppet.audio import ANALYSIS_RATE
from puppet.errors import PuppetError

RATE = ANALYSIS_RATE  # Hz
KINDS = ("music", "tones", "noise", "knocks")
KIND_WEIGHTS = (0.55, 0.1, 0.2, 0.15)  # music is the commonest sound a narration is laid over
MAJOR, MINOR = (0, 2, 4, 5, 7, 9, 11), (0, 2, 3, 5, 7, 8, 10)  # semitones of a scale
SOUNDFONTS = ("/usr/share/sounds/sf2/FluidR3_GM.sf2", "/usr/share/sounds/sf2/default-GM.sf2")
SAMPLED_SHARE = 0.75  # share of music clips played by sampled instruments, where fluidsynth can
RENDER_TIMEOUT = 60  # seconds: fluidsynth renders a clip in well under one
TICKS = 480  # MIDI ticks per beat
DRUMS = {"kick": 36, "snare": 38, "hat": 42, "open_hat": 46, "crash": 49, "tom": 45}  # General MIDI percussion keys


def sound(seconds: float, rng: np.random.Generator) -> np.ndarray:
    """(round(seconds · RATE),) float32: one clip of a kind drawn by KIND_WEIGHTS, peak 0.5."""
    kind = KINDS[rng.choice(len(KINDS), p=KIND_WEIGHTS)]
    n = round(seconds * RATE)
    clip = {"music": music, "tones": tones, "noise": noise, "knocks": knocks}[kind](n, rng)
    return _normalised(clip)


def _normalised(clip: np.ndarray) -> np.ndarray:
    peak = float(np.abs(clip).max())
    return (0.5 * clip / peak if peak > 0 else clip).astype(np.float32)


def _envelope(n: int, attack: float, decay: float) -> np.ndarray:
    """(n,) an attack of `attack` seconds, then exponential decay at `decay` per second (0: sustained)."""
    t = np.arange(n) / RATE
    return np.minimum(1.0, t / max(attack, 1e-3)) * np.exp(-decay * t)


def _pluck(frequency: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Karplus–Strong string: a noise burst circulating in a delay line of one period, low-passed each pass."""
    period = max(2, round(RATE / frequency))
    burst = np.zeros(n)
    burst[:period] = rng.uniform(-1, 1, min(period, n))
    loss = rng.uniform(0.990, 0.999)
    denominator = np.zeros(period + 2)
    denominator[0], denominator[period], denominator[period + 1] = 1.0, -0.5 * loss, -0.5 * loss
    return signal.lfilter([1.0], denominator, burst)


def _partials(frequency: float, n: int, rng: np.random.Generator, bowed: bool) -> np.ndarray:
    """Struck (decaying) or bowed/blown (sustained, vibrato) partials; bells get inharmonic ones."""
    t = np.arange(n) / RATE
    count = int(rng.integers(2, 9))
    ratios = np.arange(1, count + 1) ** (rng.uniform(1.0, 1.25) if rng.random() < 0.25 else 1.0)
    amplitudes = rng.uniform(0.3, 1.0, count) / ratios ** rng.uniform(0.5, 2.0)
    vibrato = 1 + (rng.uniform(0.002, 0.01) * np.sin(2 * np.pi * rng.uniform(4, 7) * t) if bowed else 0.0)
    phase = 2 * np.pi * frequency * np.cumsum(vibrato) / RATE
    tone = sum(a * np.sin(r * phase + rng.uniform(0, 2 * np.pi)) for a, r in zip(amplitudes, ratios) if r * frequency < RATE / 2)
    envelope = _envelope(n, rng.uniform(0.05, 0.3), rng.uniform(0.0, 1.0)) if bowed else _envelope(n, 0.003, rng.uniform(1.0, 8.0))
    return tone * envelope


def _note(frequency: float, n: int, timbre: str, rng: np.random.Generator) -> np.ndarray:
    return _pluck(frequency, n, rng) if timbre == "pluck" else _partials(frequency, n, rng, bowed=timbre == "bowed")


def _drums(n: int, beat: float, rng: np.random.Generator) -> np.ndarray:
    out, hit = np.zeros(n), int(0.25 * RATE)
    t = np.arange(hit) / RATE
    kick = np.sin(2 * np.pi * np.cumsum(45 + 120 * np.exp(-t * 35)) / RATE) * np.exp(-t * 18)
    snare = rng.normal(0, 0.5, hit) * np.exp(-t * 22) + 0.3 * np.sin(2 * np.pi * 190 * t) * np.exp(-t * 30)
    hat = signal.lfilter([1, -1], [1], rng.normal(0, 0.3, hit)) * np.exp(-t * 90)
    for k in range(int(n / RATE / (beat / 2)) + 1):
        start = int(k * beat / 2 * RATE)
        sample = kick if k % 4 == 0 else snare if k % 4 == 2 else hat
        out[start : start + hit] += sample[: max(0, n - start)]
    return out


def soundfont() -> str | None:
    """A General MIDI soundfont fluidsynth can play, or None (no fluidsynth, or no soundfont)."""
    if shutil.which("fluidsynth") is None:
        return None
    return next((path for path in SOUNDFONTS if Path(path).is_file()), None)


def _score(seconds: float, rng: np.random.Generator) -> tuple[float, list[tuple[float, float, int, int, int]]]:
    """(beats per minute, notes): each note (start beat, length in beats, channel, key, velocity) of chords
    (channel 0), a bass line (1), a melody (2) and maybe drums (9, General MIDI's percussion channel)."""
    bpm = float(rng.uniform(60, 160))
    beats = seconds * bpm / 60
    key = int(rng.integers(48, 60))
    scale = np.array(MAJOR if rng.random() < 0.6 else MINOR)

    def pitch(degree: int) -> int:
        return int(key + scale[degree % 7] + 12 * (degree // 7))

    notes, beat = [], 0.0
    while beat < beats:
        bar, root = float(rng.choice([2, 4])), int(rng.integers(0, 7))
        for degree in (root, root + 2, root + 4, root + 6)[: int(rng.integers(2, 5))]:
            notes.append((beat, bar, 0, pitch(degree), int(rng.integers(50, 90))))
        notes.append((beat, bar, 1, pitch(root) - 24, int(rng.integers(60, 100))))
        beat += bar
    beat = 0.0
    while beat < beats:
        step = float(rng.choice([0.25, 0.5, 1.0]))
        if rng.random() < 0.85:
            notes.append((beat, step, 2, pitch(int(rng.integers(7, 17))), int(rng.integers(60, 110))))
        beat += step
    if rng.random() < 0.6:
        pattern = ["kick", "hat", "snare", "hat"] if rng.random() < 0.7 else ["kick", "tom", "open_hat", "snare"]
        for k in range(int(beats * 2)):
            notes.append((k / 2, 0.25, 9, DRUMS["crash"] if k % 32 == 0 else DRUMS[pattern[k % 4]], int(rng.integers(70, 120))))
    return bpm, notes


def _midi(bpm: float, notes: list[tuple[float, float, int, int, int]], programs: tuple[int, int, int]) -> bytes:
    """A type-0 Standard MIDI File of the notes, channels 0–2 set to the given General MIDI programs."""

    def varint(n: int) -> bytes:
        out = [n & 0x7F]
        while n > 0x7F:
            n >>= 7
            out.append((n & 0x7F) | 0x80)
        return bytes(reversed(out))

    events = [(0, bytes([0xFF, 0x51, 3]) + int(60e6 / bpm).to_bytes(3, "big"))]
    events += [(0, bytes([0xC0 | channel, program])) for channel, program in enumerate(programs)]
    for start, length, channel, key, velocity in notes:
        events.append((int(start * TICKS), bytes([0x90 | channel, key, velocity])))
        events.append((int((start + length) * TICKS), bytes([0x80 | channel, key, 0])))
    events.sort(key=lambda event: (event[0], event[1][0] & 0xF0 == 0x90))  # offs before ons at one tick
    track, now = bytearray(), 0
    for tick, event in events:
        track += varint(tick - now) + event
        now = tick
    track += varint(0) + bytes([0xFF, 0x2F, 0])
    return b"MThd" + (6).to_bytes(4, "big") + (0).to_bytes(2, "big") + (1).to_bytes(2, "big") + TICKS.to_bytes(2, "big") + \
        b"MTrk" + len(track).to_bytes(4, "big") + bytes(track)


def sampled_music(n: int, rng: np.random.Generator, font: str) -> np.ndarray | None:
    """(n,) float64: `_score` played by fluidsynth with three random GM programs from `font`; None if it fails."""
    bpm, notes = _score(n / RATE, rng)
    programs = tuple(int(p) for p in rng.integers(0, 128, 3))
    with tempfile.TemporaryDirectory() as folder:
        score, played = Path(folder) / "music.mid", Path(folder) / "music.wav"
        score.write_bytes(_midi(bpm, notes, programs))
        try:
            subprocess.run(["fluidsynth", "-ni", "-g", "0.5", "-r", str(RATE), "-F", str(played), font, str(score)],
                           capture_output=True, timeout=RENDER_TIMEOUT, check=True)
            clip = audio.load(played)
        except (subprocess.SubprocessError, OSError, PuppetError):
            return None
    return np.pad(clip[:n], (0, max(0, n - len(clip)))).astype(np.float64)


def music(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) float64: chords, a bass line and a melody in one key, with or without drums; played by
    sampled instruments where fluidsynth can (SAMPLED_SHARE of clips), else synthesised."""
    font = soundfont()
    if font is not None and rng.random() < SAMPLED_SHARE:
        played = sampled_music(n, rng, font)
        if played is not None and np.abs(played).max() > 0:
            return played
    beat = 60.0 / rng.uniform(60, 160)
    key = 110.0 * 2 ** (rng.integers(0, 12) / 12)
    scale = np.array(MAJOR if rng.random() < 0.6 else MINOR)
    timbres = rng.choice(["pluck", "struck", "bowed"], 3)  # chords, bass, melody

    def pitch(degree: int, octave: int) -> float:
        return key * 2 ** (octave + (scale[degree % 7] + 12 * (degree // 7)) / 12)

    out, t = np.zeros(n), 0.0
    while t < n / RATE:
        bar = beat * rng.choice([2, 4])
        start, length = int(t * RATE), int(min(bar * 1.5, n / RATE - t) * RATE) + 1
        root = int(rng.integers(0, 7))
        for degree in (root, root + 2, root + 4, root + 6)[: int(rng.integers(2, 5))]:
            out[start : start + length] += 0.25 * _note(pitch(degree, 1), length, timbres[0], rng)[: n - start]
        out[start : start + length] += 0.4 * _note(pitch(root, 0) / 2, length, timbres[1], rng)[: n - start]
        t += bar
    if rng.random() < 0.8:
        t = 0.0
        while t < n / RATE:
            step = beat * rng.choice([0.25, 0.5, 1.0])
            start, length = int(t * RATE), int(min(step * 1.2, n / RATE - t) * RATE) + 1
            if rng.random() < 0.85:
                out[start : start + length] += 0.3 * _note(pitch(int(rng.integers(0, 10)), 2), length, timbres[2], rng)[: n - start]
            t += step
    if rng.random() < 0.6:
        out += rng.uniform(0.3, 1.0) * _drums(n, beat, rng) * np.abs(out).max()
    return out


def tones(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) float64: beeps, whistles, sirens and chimes."""
    t = np.arange(n) / RATE
    base = rng.uniform(300, 3000)
    if rng.random() < 0.5:  # gliding: a whistle or a siren
        frequency = base * 2 ** (rng.uniform(0.2, 1.0) * np.sin(2 * np.pi * rng.uniform(0.2, 3) * t))
    else:  # stepping: beeps and chimes
        steps = base * 2 ** (rng.integers(-7, 8, size=int(n / RATE * 4) + 1) / 12)
        frequency = steps[(t * 4).astype(int)]
    phase = 2 * np.pi * np.cumsum(frequency) / RATE
    tone = np.sin(phase) + rng.uniform(0, 0.5) * np.sin(2 * phase)
    gate = (np.sin(2 * np.pi * rng.uniform(0.5, 4) * t) > rng.uniform(-1, 0.5)).astype(float)
    return tone * signal.lfilter([0.02], [1, -0.98], gate)


def noise(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) float64: coloured noise through a random band, swelling and fading; or mains hum."""
    t = np.arange(n) / RATE
    if rng.random() < 0.2:
        mains = rng.choice([50.0, 60.0])
        return sum(rng.uniform(0.1, 1) / k * np.sin(2 * np.pi * mains * k * t) for k in range(1, 8)) + rng.normal(0, 0.02, n)
    white = rng.normal(0, 1, n)
    colour = rng.choice(["white", "pink", "brown"])
    if colour == "pink":
        white = signal.lfilter([0.049922, -0.095993, 0.050612, -0.004408], [1, -2.494956, 2.017265, -0.522190], white)
    elif colour == "brown":
        white = signal.lfilter([1.0], [1, -0.995], white)
    low = rng.uniform(50, 2000)
    band = signal.butter(2, [low, min(low * rng.uniform(2, 30), RATE / 2 - 100)], "bandpass", fs=RATE, output="sos")
    swell = 1 + rng.uniform(0, 0.8) * np.sin(2 * np.pi * rng.uniform(0.05, 1) * t + rng.uniform(0, 6.3))
    return signal.sosfilt(band, white) * swell


def knocks(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) float64: clicks, taps, claps and typing, at random times."""
    out = np.zeros(n)
    rate = rng.uniform(1, 12)  # events per second
    for start in np.sort(rng.integers(0, n, size=int(rng.poisson(rate * n / RATE)) + 1)):
        length = int(rng.uniform(0.01, 0.12) * RATE)
        t = np.arange(length) / RATE
        burst = rng.normal(0, 1, length) if rng.random() < 0.6 else np.sin(2 * np.pi * rng.uniform(200, 3000) * t)
        burst = burst * np.exp(-t * rng.uniform(30, 200)) * rng.uniform(0.2, 1)
        low = rng.uniform(100, 3000)
        sos = signal.butter(2, [low, min(low * 4, RATE / 2 - 100)], "bandpass", fs=RATE, output="sos")
        out[start : start + length] += signal.sosfilt(sos, burst)[: n - start]
    return out
