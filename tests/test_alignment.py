import itertools
import json
import shutil
import subprocess

import numpy as np
import pytest
from conftest import SHARED_MEDIA

from puppet import audio
from puppet.alignment import PHONES, SILENCE, _poor_fits, align, align_checked, guess_pronunciation, normalise
from puppet.errors import PuppetError

REFERENCES = sorted((SHARED_MEDIA / "speech").glob("*.phone.json"))
FRAME = 0.01  # seconds: the resolution at which alignments are compared


def frame_labels(phones: list[tuple[str, float, float]], n_frames: int) -> np.ndarray:
    labels = np.full(n_frames, SILENCE, dtype=object)
    for name, start, end in phones:
        labels[round(start / FRAME):round(end / FRAME)] = name
    return labels


def espeak(tmp_path, text: str, voice: str = "en-us") -> np.ndarray:
    if shutil.which("espeak-ng") is None:
        pytest.skip("espeak-ng is not installed")
    path = tmp_path / "speech.wav"
    subprocess.run(["espeak-ng", "-v", voice, "-w", str(path), text], check=True)
    return audio.load(path)


def assert_tiles(phones, duration):
    assert phones[0].start == 0.0 and phones[-1].end == pytest.approx(duration, abs=1e-6)
    for before, after in itertools.pairwise(phones):
        assert before.end == after.start and after.end > after.start
    assert {p.phone for p in phones} <= set(PHONES) | {SILENCE}


@pytest.mark.skipif(not REFERENCES, reason="../shared/media/speech is not here")
@pytest.mark.parametrize("reference", REFERENCES, ids=lambda path: path.name.split(".")[0][-4:])
def test_real_speech_aligns_like_the_reference_phones(reference):
    base = reference.with_name(reference.name.removesuffix(".phone.json"))
    samples = audio.load(base.with_suffix(".wav"))
    phones = align(samples, base.with_suffix(".txt").read_text())
    assert_tiles(phones, len(samples) / 16000)
    expected = [(phone["t"] if phone["t"] in PHONES else SILENCE, phone["b"], phone["b"] + phone["d"])
                for word in json.loads(reference.read_text())["w"] for phone in word["w"]]
    n_frames = int(len(samples) / 16000 / FRAME)
    agreement = np.mean(frame_labels([(p.phone, p.start, p.end) for p in phones], n_frames)
                        == frame_labels(expected, n_frames))
    assert agreement > 0.95
    boundaries = np.array([p.start for p in phones[1:]])
    errors = [np.abs(boundaries - start).min() for _, start, _ in expected[1:]]
    assert np.median(errors) <= 0.02


def test_synthetic_speech_is_covered_from_start_to_end_with_the_words_phones(tmp_path):
    samples = espeak(tmp_path, "Bob met my mother by the pool")
    phones = align(samples, "Bob met my mother by the pool")
    assert_tiles(phones, len(samples) / 16000)
    spoken = [p.phone for p in phones if p.phone != SILENCE]
    assert spoken[:3] == ["B", "AA", "B"] and spoken[-3:] == ["P", "UW", "L"]


def test_words_missing_from_the_dictionary_get_a_guessed_pronunciation(tmp_path):
    assert guess_pronunciation("zorblax") == "Z AO R B L AE K S"
    assert guess_pronunciation("whooshed").startswith("W UW SH")
    samples = espeak(tmp_path, "the zorblax sleeps")
    phones = align(samples, "The zorblax sleeps.")
    assert_tiles(phones, len(samples) / 16000)
    assert "Z" in [p.phone for p in phones]


def test_transcripts_are_normalised_to_dictionary_words():
    assert normalise("It's 3 a.m.! 1984 & 12%") == [
        "it's", "three", "a", "m", "one", "thousand", "nine", "hundred", "eighty", "four", "and", "twelve", "percent"]


def test_impossible_alignments_raise_a_clear_error():
    with pytest.raises(PuppetError, match="nothing to align"):
        align(np.zeros(16000, np.float32), "?!")
    with pytest.raises(PuppetError, match="cannot align"):
        align(np.zeros(800, np.float32), "the quick brown fox jumps over the lazy dog again and again")


def test_the_right_words_fit_and_other_words_are_found_where_they_are(demo_speech):
    samples, text = audio.load(demo_speech), demo_speech.with_suffix(".txt").read_text()
    phones, misfits = align_checked(samples, text)
    assert phones == align(samples, text) and misfits == []
    sentence = text.split(".")[1]
    assert sentence.split()[0] == "Give" and text.split(".")[2].split()[0] == "Who"
    start = next(p.start for p in phones if p.phone == "G")  # "Give me any picture and a voice, and watch me talk."
    end = next(p.start for p in phones if p.phone == "HH" and p.start > start)  # "Who ..."
    swapped = text.replace(sentence, " The quick brown fox jumps over the lazy dog", 1)
    (misfit,) = align_checked(samples, swapped)[1]
    assert start <= misfit[0] and misfit[1] <= end and misfit[1] - misfit[0] > 1.0


def test_poor_fits_are_runs_of_a_low_windowed_score_with_near_runs_merged():
    free = [(0, 600, 0.0)]
    aligned = [(0, 100, 0.0), (100, 150, -150 * 50.0), (150, 170, 0.0), (170, 220, -150 * 50.0), (220, 600, 0.0)]
    ((start, end),) = _poor_fits(aligned, free, frame_rate=100)  # -15,000 a second over 1 s windows, in two bursts
    assert 50 < start < 150 and 170 < end < 270  # within half a window of the bursts
    assert _poor_fits([(0, 600, -20.0 * 600)], free, frame_rate=100) == []  # -2,000 a second throughout: fits
