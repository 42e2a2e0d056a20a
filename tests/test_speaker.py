import numpy as np
from conftest import shared

from puppet import audio, speaker


def test_embedding_is_a_finite_unit_vector_even_for_silence_and_noise(demo_speech):
    voice = audio.load(demo_speech)
    for samples in [voice, np.zeros(16000, np.float32), np.random.default_rng(0).normal(0, 0.3, 8000).astype(np.float32), voice[:100]]:
        e = speaker.embed(samples)
        assert e.shape == (speaker.EMBEDDING_SIZE,) and np.isfinite(e).all()
        assert abs(np.linalg.norm(e) - 1) < 1e-4 or np.linalg.norm(e) == 0


def test_the_same_voice_is_closer_than_another_voice(demo_speech):
    voice = audio.load(demo_speech)
    half = len(voice) // 2
    first, second = speaker.embed(voice[:half]), speaker.embed(voice[half:])
    other = speaker.embed(audio.load(shared("speech", "goforward.wav")))
    assert first @ second > first @ other + 0.1


def test_partials_cover_the_utterance():
    slices = speaker.partial_slices(16000 * 5)
    assert slices[0].start == 0 and slices[-1].stop * speaker.HOP >= 16000 * 5 * speaker.MIN_COVERAGE
    assert all(s.stop - s.start == speaker.PARTIAL_FRAMES for s in slices)
    assert len(speaker.partial_slices(100)) == 1


def test_silences_are_cut_but_speech_is_kept(demo_speech):
    voice = audio.load(demo_speech)
    padded = np.concatenate([np.zeros(16000 * 3, np.float32), voice])
    assert abs(len(speaker.prepare(padded)) - len(speaker.prepare(voice))) < 16000 * 0.6
