import itertools
import json
import shutil
import subprocess

import numpy as np
import pytest
from conftest import SHARED_MEDIA
from pocketsphinx import Decoder

from puppet import audio
from puppet.alignment import (
    PHONES,
    SILENCE,
    Cue,
    _poor_fits,
    align,
    align_checked,
    common_runs,
    guess_pronunciation,
    heard,
    normalise,
    script_language_model,
)
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
    for aligner in align, align_checked:
        with pytest.raises(PuppetError, match="nothing to align"):
            aligner(np.zeros(16000, np.float32), "?!")
    with pytest.raises(PuppetError, match="cannot align.*are those the words spoken") as error:
        align(np.zeros(800, np.float32), "the quick brown fox jumps over the lazy dog again and again")
    assert "\n" not in str(error.value)  # one line


def test_the_right_words_fit_and_other_words_are_found_where_they_are(demo_speech):
    samples, text = audio.load(demo_speech), demo_speech.with_suffix(".txt").read_text()
    aligned = align_checked(samples, text)
    phones = aligned.phones
    assert phones == align(samples, text) and aligned.misfits == aligned.unsaid == []
    sentence = text.split(".")[1]
    assert sentence.split()[0] == "Give" and text.split(".")[2].split()[0] == "Who"
    start = next(p.start for p in phones if p.phone == "G")  # "Give me any picture and a voice, and watch me talk."
    end = next(p.start for p in phones if p.phone == "HH" and p.start > start)  # "Who ..."
    swapped = text.replace(sentence, " The quick brown fox jumps over the lazy dog", 1)
    (misfit,) = align_checked(samples, swapped).misfits
    assert start <= misfit[0] and misfit[1] <= end and misfit[1] - misfit[0] > 1.0


def test_without_a_transcript_the_words_heard_are_aligned(demo_speech):
    """The recogniser's words for the demo ("i bet your pocket … a blob pixels could be this much fun")
    are often wrong, but their phones fall on 84 % of 10 ms frames as the transcript's do."""
    samples, text = audio.load(demo_speech), demo_speech.with_suffix(".txt").read_text()
    recognised = heard(samples)
    duration = len(samples) / 16000
    assert_tiles(recognised.phones, duration)
    n = round(duration / FRAME)
    as_heard = frame_labels([(p.phone, p.start, p.end) for p in recognised.phones], n)
    as_written = frame_labels([(p.phone, p.start, p.end) for p in align(samples, text)], n)
    assert np.mean(as_heard == as_written) > 0.75


def test_poor_fits_are_runs_of_a_low_windowed_score_with_near_runs_merged():
    free = [(0, 600, 0.0)]
    aligned = [(0, 100, 0.0), (100, 150, -150 * 50.0), (150, 170, 0.0), (170, 220, -150 * 50.0), (220, 600, 0.0)]
    ((start, end),) = _poor_fits(aligned, free, frame_rate=100)  # -15,000 a second over 1 s windows, in two bursts
    assert 50 < start < 150 and 170 < end < 270  # within half a window of the bursts
    assert _poor_fits([(0, 600, -20.0 * 600)], free, frame_rate=100) == []  # -2,000 a second throughout: fits


def demo_cues(demo_speech):
    """The demo's three sentences as subtitle cues timed from its whole alignment (±0.1 s), and that alignment."""
    samples, text = audio.load(demo_speech), demo_speech.with_suffix(".txt").read_text()
    phones = align(samples, text)
    starts = [next(p.start for p in phones if p.phone == first) for first in ("HH", "G")]
    starts.append(next(p.start for p in phones if p.phone == "HH" and p.start > starts[1]))  # "Hi", "Give", "Who"
    ends = [max(p.end for p in phones if p.phone != SILENCE and p.end <= nxt) for nxt in starts[1:] + [99.0]]
    sentences = [sentence.strip() + "." for sentence in text.split(".") if sentence.strip()]
    return samples, phones, [Cue(a - 0.1, b + 0.1, words) for a, b, words in zip(starts, ends, sentences)]


def test_subtitle_cues_align_within_their_times_and_a_wrong_cue_upsets_only_itself(demo_speech):
    samples, whole, cues = demo_cues(demo_speech)
    assert len(cues) == 3 and cues[1].text.startswith("Give")
    n = int(len(samples) / 16000 / FRAME)
    aligned = align_checked(samples, tuple(cues))
    phones = aligned.phones
    assert_tiles(phones, len(samples) / 16000)
    assert aligned.misfits == [] and aligned.unsaid == ([(0.0, cues[0].start - 0.5)] if cues[0].start > 0.5 else [])
    agree = frame_labels([(p.phone, p.start, p.end) for p in phones], n) == frame_labels([(p.phone, p.start, p.end) for p in whole], n)
    assert agree.mean() > 0.9
    cues[1] = Cue(cues[1].start, cues[1].end, "The quick brown fox jumps over the lazy dog.")
    aligned = align_checked(samples, tuple(cues))
    phones, misfits = aligned.phones, aligned.misfits
    assert misfits and all(cues[1].start - 0.5 <= a < b <= cues[1].end + 0.5 for a, b in misfits)
    labels = frame_labels([(p.phone, p.start, p.end) for p in phones], n)
    others = np.r_[0:int(cues[0].end / FRAME), int(cues[2].start / FRAME):n]
    assert (labels == frame_labels([(p.phone, p.start, p.end) for p in whole], n))[others].mean() > 0.9


def test_common_runs_pair_words_in_order_early_and_past_repeats_and_gaps():
    assert common_runs(list("abc"), list("abcabc")) == [(0, 0, 3)]  # a repeated line: the first time
    assert common_runs(list("abcdxyz"), list("abcqqxyz")) == [(0, 0, 3), (4, 5, 3)]  # "d" unsaid, "qq" unscripted
    assert common_runs(list("ab"), []) == common_runs([], list("ab")) == []


def test_the_script_language_model_follows_the_script_and_loads_into_pocketsphinx(tmp_path):
    model = script_language_model(["the", "cat", "the", "dog"])
    bigrams = {" ".join(line.split()[1:]): float(line.split()[0]) for line in model.split("\\2-grams:")[1].splitlines()[1:-2]}
    assert bigrams == pytest.approx({"<s> the": np.log10(0.9), "the cat": np.log10(0.45), "the dog": np.log10(0.45),
                                     "cat the": np.log10(0.9), "dog </s>": np.log10(0.9)}, abs=1e-4)
    (tmp_path / "script.arpa").write_text(script_language_model(["yes", "yes"]))  # every word follows every word
    decoder = Decoder(samprate=16000, loglevel="FATAL")
    decoder.add_lm_file("script", str(tmp_path / "script.arpa"))


def test_a_script_that_skips_a_sentence_is_anchored_and_the_rest_placed_as_in_the_full_script(demo_speech):
    samples, whole, cues = demo_cues(demo_speech)
    n = int(len(samples) / 16000 / FRAME)
    skipped = align_checked(samples, f"{cues[0].text} {cues[2].text}")  # "Give me any picture ..." said, not written
    assert_tiles(skipped.phones, len(samples) / 16000)
    (misfit,) = skipped.misfits
    assert cues[1].start - 0.3 <= misfit[0] and misfit[1] <= cues[1].end + 0.3  # the unwritten sentence, nearly all of it
    assert misfit[1] - misfit[0] > 0.8 * (cues[1].end - cues[1].start)
    labels = frame_labels([(p.phone, p.start, p.end) for p in skipped.phones], n)
    others = np.r_[0:int(cues[0].end / FRAME), int(cues[2].start / FRAME):n]
    assert (labels == frame_labels([(p.phone, p.start, p.end) for p in whole], n))[others].mean() > 0.95


def test_long_audio_is_anchored_in_short_pieces_and_placed_as_when_aligned_whole(demo_speech, monkeypatch):
    """A forced alignment's memory grows with the square of its length (6 minutes whole: 3.2 GB; anchored
    in pieces of at most 20 s: 0.47 GB, 99 % of frames as whole). Here the demo stands in for long audio."""
    from puppet import alignment

    samples, text = audio.load(demo_speech), demo_speech.with_suffix(".txt").read_text()
    whole = align(samples, text)
    monkeypatch.setattr(alignment, "LONG_AUDIO_SECONDS", 5.0)
    monkeypatch.setattr(alignment, "MAX_CUE_SECONDS", 2.0)
    pieces = []
    align_cues = alignment.Aligner.align_cues
    monkeypatch.setattr(alignment.Aligner, "align_cues", lambda self, s, cues: pieces.extend(cues) or align_cues(self, s, cues))
    anchored = alignment.Aligner().align_checked(samples, text)
    assert len(pieces) >= 4 and max(cue.end - cue.start for cue in pieces) < 2.0 + 1.0  # ends at the word that crosses 2 s
    assert anchored.misfits == []
    n = int(len(samples) / 16000 / FRAME)
    as_whole = frame_labels([(p.phone, p.start, p.end) for p in whole], n)
    assert (frame_labels([(p.phone, p.start, p.end) for p in anchored.phones], n) == as_whole).mean() > 0.95
