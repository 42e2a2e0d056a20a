import json

import numpy as np
import pytest
from conftest import SHARED_MEDIA

from puppet import audio
from puppet.alignment import Phone
from puppet.prosody import MAX_DEGREES, head_motion, pitch, style_for

RATE = 16000
SPEECH = SHARED_MEDIA / "speech" / "sense_and_sensibility_01_austen_64kb-0870"


def sung(seconds_and_hz: list[tuple[float, float]]) -> tuple[np.ndarray, list[Phone]]:
    """A buzzy vowel per (seconds, f0) pair with 0.3 s pauses around, and its phones."""
    pieces, phones, time = [np.zeros(int(0.3 * RATE), np.float32)], [Phone("SIL", 0.0, 0.3)], 0.3
    for seconds, hz in seconds_and_hz:
        t = np.arange(int(seconds * RATE)) / RATE
        loud = 0.6 if hz > 200 else 0.15
        pieces.append((loud * np.sign(np.sin(2 * np.pi * hz * t)) * np.hanning(len(t))).astype(np.float32))
        phones.append(Phone("AA", time, time + seconds))
        time += seconds
    pieces.append(np.zeros(int(0.3 * RATE), np.float32))
    phones.append(Phone("SIL", time, time + 0.3))
    return np.concatenate(pieces), phones


def test_pitch_finds_the_fundamental_and_nothing_in_silence():
    t = np.arange(RATE) / RATE
    for hz in (90.0, 150.0, 280.0):
        f0 = pitch((0.3 * np.sin(2 * np.pi * hz * t)).astype(np.float32))
        assert np.median(f0[5:-5]) == pytest.approx(hz, rel=0.03)
    assert np.all(pitch(np.zeros(RATE, np.float32)) == 0)


def test_styles_are_the_same_for_a_speaker_and_differ_between_speakers():
    assert style_for("voice-a") == style_for("voice-a")
    styles = [style_for(f"voice-{i}") for i in range(20)]
    assert len({s.amplitude for s in styles}) == 20 and len({s.nod > 0.5 for s in styles}) == 2


def test_accents_move_the_head_and_brows_within_bounds_and_differently_per_voice():
    samples, phones = sung([(0.2, 120), (0.2, 120), (0.25, 260), (0.2, 120), (0.2, 120), (0.25, 250), (0.2, 120)])
    n_frames = int(phones[-1].end * 50)
    motions = {speaker: head_motion(samples, phones, n_frames, style_for(speaker)) for speaker in ("ann", "bob")}
    for rotation, brow in motions.values():
        assert rotation.shape == (n_frames, 3) and rotation.dtype == np.float32
        assert brow.shape == (n_frames,) and brow.dtype == np.float32
        assert np.all(np.abs(rotation) <= np.radians(MAX_DEGREES)) and 0 <= brow.min() and brow.max() <= 1
        accent = int((phones[3].start + phones[3].end) / 2 * 50)
        assert brow[accent] > 0.05 and brow[accent] > brow[int(phones[1].end * 50) - 2]  # brows lift on the high note
        assert np.degrees(np.abs(rotation[accent])).max() > 0.5
        assert np.degrees(np.abs(np.diff(rotation, axis=0))).max() < 1.0  # smooth: under 1° per frame
    again = head_motion(samples, phones, n_frames, style_for("ann"))
    np.testing.assert_array_equal(again[0], motions["ann"][0])
    assert np.abs(motions["ann"][0] - motions["bob"][0]).max() > np.radians(0.3)


def test_real_speech_nods_on_accents_within_bounds():
    if not SPEECH.with_suffix(".wav").exists():
        pytest.skip("../shared/media/speech is not here")
    samples = audio.load(SPEECH.with_suffix(".wav"))
    reference = json.loads(SPEECH.with_suffix(".phone.json").read_text())
    phones = [Phone(phone["t"], phone["b"], phone["b"] + phone["d"]) for word in reference["w"] for phone in word["w"]]
    rotation, brow = head_motion(samples, phones, 355, style_for("reader"))
    assert 0.5 < np.degrees(np.abs(rotation)).max() <= MAX_DEGREES
    assert brow.max() > 0.05
