import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import drawn_face
from scipy.io import wavfile

from puppet import audio, bundle
from puppet.landmarks import INNER_LIP_PAIRS, MOUTH, face_scale, load, with_depth
from puppet.loudness import (
    MAX_NOD_DEGREES,
    LoudnessOptions,
    frame_count,
    loudness_motion,
)

RATE = 16000
FPS = 25.0
# Real read speech with word timings, beside the repository when available.
SPEECH = sorted((Path(__file__).resolve().parents[2] / "shared" / "media" / "speech").glob("*.json"))
SPEECH = [path for path in SPEECH if not path.name.endswith(".phone.json")]




REST = drawn_face()
IOD = 100.0


def voice(seconds, f0=120.0, formants=(700.0, 1200.0), seed=0):
    """(N,) float32 voiced-like sound: harmonics of f0 shaped by two formant peaks, plus breath noise."""
    t = np.arange(int(seconds * RATE)) / RATE
    wobble = 1.0 + 0.02 * np.sin(2 * np.pi * 5.0 * t)  # a little vibrato, like a real voice
    sound = np.zeros_like(t)
    for k in range(1, int(4000 / f0)):
        gain = sum(1.0 / (1.0 + ((k * f0 - f) / 150.0) ** 2) for f in formants) + 0.02
        sound += gain * np.sin(2 * np.pi * k * f0 * np.cumsum(wobble) / RATE)
    sound += 0.05 * np.random.default_rng(seed).standard_normal(len(t))
    return (sound / np.abs(sound).max()).astype(np.float32)


def speech(phrases=3, phrase_seconds=1.0, pause_seconds=0.6, level=0.5):
    """(N,) float32: phrases of 4 Hz syllables separated by silent pauses, then the phrase boundaries in s."""
    pieces, spans, time = [], [], 0.0
    for i in range(phrases):
        silence = np.zeros(int(pause_seconds * RATE), np.float32)
        t = np.arange(int(phrase_seconds * RATE)) / RATE
        syllables = np.sin(np.pi * 4.0 * t) ** 2  # 4 syllables per second, each fading to nothing
        pieces += [silence, voice(phrase_seconds, seed=i) * syllables]
        spans.append((time + pause_seconds, time + pause_seconds + phrase_seconds))
        time += pause_seconds + phrase_seconds
    pieces.append(np.zeros(int(pause_seconds * RATE), np.float32))
    return (level * np.concatenate(pieces)).astype(np.float32), spans


def lip_gap(motion):
    """(T,) inner-lip opening beyond the rest opening, in inter-ocular distances."""
    points = REST + motion.offsets
    gap = np.mean([points[:, lower, 1] - points[:, upper, 1] for upper, lower in INNER_LIP_PAIRS], axis=0)
    rest_gap = np.mean([REST[lower, 1] - REST[upper, 1] for upper, lower in INNER_LIP_PAIRS])
    return (gap - rest_gap) / IOD


def frames_within(start, end):
    return slice(math.ceil(start * FPS), math.floor(end * FPS))


def test_silence_keeps_the_mouth_shut_and_the_head_still():
    motion = loudness_motion(np.zeros(2 * RATE, np.float32), RATE, REST, FPS)
    assert len(motion) == 50
    assert np.all(motion.offsets == 0) and np.all(motion.rotation == 0) and np.all(motion.translation == 0)


def test_the_mouth_opens_in_speech_and_closes_in_the_pauses():
    audio, spans = speech()
    motion = loudness_motion(audio, RATE, REST, FPS)
    gap = lip_gap(motion)
    edges = [0.0, *np.ravel(spans), len(audio) / RATE]
    pauses = list(zip(edges[::2], edges[1::2]))
    for start, end in spans:
        assert gap[frames_within(start, end)].max() > 0.15  # clearly open on every phrase
    for start, end in pauses:
        middle = frames_within(start + 0.3, end - 0.1)
        assert np.all(np.abs(gap[middle]) < 1e-3), (start, end)  # shut, not just nearly
        assert np.all(motion.offsets[middle][:, MOUTH] == 0)
        assert np.abs(motion.offsets[middle]).max() < 0.02 * IOD  # an emphasised phrase's brows are settling


def test_background_hiss_between_phrases_leaves_the_mouth_shut():
    audio, spans = speech()
    voiced = np.concatenate([audio[int(a * RATE):int(b * RATE)] for a, b in spans])
    hiss_rms = np.sqrt(np.mean(voiced ** 2)) * 10 ** (-22 / 20)  # 22 dB below the speech
    noisy = audio + np.random.default_rng(0).normal(0.0, hiss_rms, len(audio)).astype(np.float32)
    gap = lip_gap(loudness_motion(noisy, RATE, REST, FPS))
    edges = [0.0, *np.ravel(spans), len(audio) / RATE]
    for start, end in zip(edges[::2], edges[1::2]):
        assert np.all(gap[frames_within(start + 0.3, end - 0.1)] < 0.005)
    for start, end in spans:
        assert gap[frames_within(start, end)].max() > 0.15


@pytest.mark.skipif(not SPEECH, reason="../shared/media/speech is not here")
@pytest.mark.parametrize("path", SPEECH, ids=lambda path: path.stem[-4:])
def test_real_speech_opens_the_mouth_on_words_and_not_in_silences(path):
    rate, samples = wavfile.read(path.with_suffix(".wav"))
    gap = lip_gap(loudness_motion(samples.astype(np.float32) / 32768.0, rate, REST, FPS))
    for word in json.load(open(path))["w"]:
        frames = frames_within(word["b"], word["b"] + word["d"])
        if word["t"] == "<sil>" and word["d"] >= 0.2:
            assert gap[frames].mean() < 0.02, word
        elif word["t"] != "<sil>" and word["d"] >= 0.15:
            assert gap[frames].max() > 0.03, word  # even "be" parts the lips visibly


def test_pip_talks_with_the_bundled_speech_and_is_shut_before_and_after():
    _, landmarks, speech_wav = bundle.demo_files()
    rest = with_depth(load(landmarks))
    motion = loudness_motion(audio.load(speech_wav), audio.ANALYSIS_RATE, rest, FPS)
    points = rest + motion.offsets
    gap = np.mean([points[:, b, 1] - points[:, a, 1] for a, b in INNER_LIP_PAIRS], 0) / face_scale(rest)
    assert len(motion) == 200  # 8.0 s at 25 fps
    assert np.all(gap[:5] == 0) and np.all(gap[-3:] < 0.005)  # the clip has 0.3 s of silence at each end
    assert np.mean(gap > 0.05) > 0.4 and gap.max() > 0.15


def test_the_mouth_follows_the_syllables():
    audio, spans = speech(phrases=1, phrase_seconds=2.0)
    gap = lip_gap(loudness_motion(audio, RATE, REST, FPS))[frames_within(*spans[0])]
    peaks = np.flatnonzero((gap[1:-1] > gap[:-2]) & (gap[1:-1] >= gap[2:]) & (gap[1:-1] > 0.1))
    assert len(peaks) == 8  # one opening per syllable, 4 syllables a second
    assert gap.min() < 0.5 * gap.max()  # and it closes at least half-way between them


def test_a_quieter_recording_of_the_same_speech_moves_the_same():
    audio, _ = speech()
    loud = loudness_motion(audio, RATE, REST, FPS)
    quiet = loudness_motion(audio * 0.1, RATE, REST, FPS)  # 20 dB down
    assert np.abs(quiet.offsets - loud.offsets).max() < 0.01 * IOD
    assert np.abs(quiet.rotation - loud.rotation).max() < np.radians(0.1)


def test_bright_vowels_widen_the_lips_and_dark_ones_round_them():
    ee = voice(0.8, formants=(300.0, 2300.0))
    oo = voice(0.8, formants=(300.0, 800.0))
    gap = np.zeros(int(0.5 * RATE), np.float32)
    audio = 0.5 * np.concatenate([gap, ee, gap, oo, gap])
    points = REST + loudness_motion(audio, RATE, REST, FPS).offsets
    width = points[:, 54, 0] - points[:, 48, 0]
    assert width[frames_within(0.7, 1.2)].mean() > width[frames_within(2.0, 2.5)].mean() + 0.05 * IOD


@pytest.mark.parametrize("samples, fps, frames", [
    (RATE, 25.0, 25), (RATE + 1, 25.0, 26), (RATE - 1, 25.0, 25), (3 * RATE, 29.97, 90),
    (RATE // 2, 30.0, 15), (1, 25.0, 1), (0, 25.0, 0),
])
def test_one_frame_per_started_frame_interval_of_sound(samples, fps, frames):
    assert frame_count(samples, RATE, fps) == frames == math.ceil(samples / RATE * fps - 1e-9)
    assert len(loudness_motion(np.full(samples, 0.1, np.float32), RATE, REST, fps)) == frames


@pytest.mark.parametrize("name", ["white noise", "clipped", "all zero", "tiny", "nan"])
def test_odd_inputs_give_finite_bounded_motion(name):
    rng = np.random.default_rng(3)
    audio = {
        "white noise": rng.uniform(-1, 1, 2 * RATE).astype(np.float32),
        "clipped": np.clip(speech()[0] * 20, -1, 1),
        "all zero": np.zeros(RATE, np.float32),
        "tiny": np.full(100, 0.5, np.float32),
        "nan": np.where(rng.random(RATE) < 0.01, np.nan, rng.uniform(-0.5, 0.5, RATE)).astype(np.float32),
    }[name]
    motion = loudness_motion(audio, RATE, REST, FPS)
    assert len(motion) == frame_count(len(audio), RATE, FPS)
    for array in (motion.offsets, motion.rotation, motion.translation):
        assert np.all(np.isfinite(array))
    assert np.abs(motion.offsets).max() <= 0.5 * IOD
    assert np.degrees(np.abs(motion.rotation)).max() <= MAX_NOD_DEGREES + 1e-4


def test_emphasis_nods_a_little_and_never_past_the_cap():
    audio, spans = speech()
    motion = loudness_motion(audio, RATE, REST, FPS, LoudnessOptions(nod_degrees=10.0))
    pitch = np.degrees(motion.rotation[:, 0])
    assert 0.5 < pitch.max() <= MAX_NOD_DEGREES + 1e-4
    assert np.all(motion.rotation[:, 1:] == 0)
