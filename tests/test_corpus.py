"""Training corpus: text the aligner can read, files that keep the contract, held-out speakers that stay
held out, the same corpus for a seed, and a rerun that picks up where the last one stopped."""
import json
import wave
from dataclasses import replace
from itertools import pairwise

import numpy as np
import pytest

pytest.importorskip("pocketsphinx")

from puppet import corpus
from puppet.alignment import PHONES, SILENCE
from puppet.corpus import CorpusOptions, Voice

TRAIN_VOICE = Voice("espeak-ng", "en-us")
HELDOUT_VOICE = Voice("espeak-ng", "en-gb-scotland")  # in HELDOUT_VOICES
TINY_HOURS = 20 / 3600  # 20 s of audio


def sentences(count, seed=0, kinds=corpus.TEXT_KINDS):
    texts = corpus.TextSource(np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    return {kind: [texts.sentence(kind, rng) for _ in range(count)] for kind in kinds}


def test_every_spoken_word_is_in_the_dictionary():
    lexicon = corpus.lexicon()
    for kind, texts in sentences(40).items():
        for text in texts:
            words = corpus.words_of(text)
            assert words, (kind, text)
            assert all(w in lexicon for w in words), (kind, text)
            assert text[0].isupper() and text[-1] in ".?!"
    coverage = sentences(40, kinds=["coverage"])["coverage"]
    assert all(corpus.SENTENCE_WORDS[0] <= len(corpus.words_of(t)) <= corpus.SENTENCE_WORDS[1] for t in coverage)


def test_coverage_sentences_reach_nearly_every_phone_and_many_phone_pairs():
    lexicon = corpus.lexicon()
    phones = [p for text in sentences(150, kinds=["coverage"])["coverage"] for w in corpus.words_of(text) for p in lexicon[w]]
    all_phones = {p for pronunciation in lexicon.values() for p in pronunciation}
    assert len(set(phones)) >= len(all_phones) - 1  # 39 CMU phones
    assert len(set(pairwise(phones))) > 800


def test_text_is_the_same_for_a_seed_and_differs_between_seeds():
    assert sentences(5, seed=3) == sentences(5, seed=3)
    assert sentences(5, seed=3) != sentences(5, seed=4)


def test_plan_holds_out_whole_speakers_by_the_rule():
    voices = corpus.VOICES
    planned = [u for _, u in zip(range(600), corpus.plan(0, voices))]
    for u in planned:
        assert u.heldout == (u.voice in corpus.HELDOUT_VOICES or u.identity == corpus.HELDOUT_IDENTITY)
    by_speaker = {}
    for u in planned:
        by_speaker.setdefault(corpus.speaker_id(u.voice, u.identity), set()).add(u.heldout)
    assert all(len(flags) == 1 for flags in by_speaker.values())
    share = np.mean([u.heldout for u in planned])
    assert 0.05 < share < 0.16
    assert {u.voice.engine for u in planned} == {"espeak-ng", "flite", "festival", "piper"}
    again = [u for _, u in zip(range(50), corpus.plan(0, voices))]
    assert again == planned[:50]


def read_wav(path):
    with wave.open(str(path), "rb") as f:
        assert (f.getnchannels(), f.getsampwidth(), f.getframerate()) == (1, 2, corpus.RATE)
        return np.frombuffer(f.readframes(f.getnframes()), "<i2")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 20 s corpus of two espeak-ng voices, one of them held out."""
    if not corpus.installed((TRAIN_VOICE,)):
        pytest.skip("espeak-ng is not installed")
    folder = tmp_path_factory.mktemp("corpus")
    options = CorpusOptions(hours=TINY_HOURS, seed=1, jobs=1, voices=(TRAIN_VOICE, HELDOUT_VOICE))
    corpus.build(folder, options)
    return folder, options


def manifest(folder):
    return [json.loads(line) for line in (folder / corpus.MANIFEST).read_text().splitlines()]


def test_tiny_corpus_keeps_the_contract(tiny):
    folder, _ = tiny
    entries = manifest(folder)
    assert sum(e["seconds"] for e in entries) >= 20
    assert sum(e["seconds"] for e in entries[:-1]) < 20  # stops as soon as it has enough
    lexicon = corpus.lexicon()
    for e in entries:
        assert set(e) == {"id", "text", "engine", "voice", "speaker", "heldout", "seconds", "augment"}
        assert e["engine"] == "espeak-ng" and e["voice"] in (TRAIN_VOICE.name, HELDOUT_VOICE.name)
        assert all(w in lexicon for w in corpus.words_of(e["text"]))
        heard, clean = read_wav(folder / "audio" / f"{e['id']}.wav"), read_wav(folder / "clean" / f"{e['id']}.wav")
        assert len(heard) == len(clean) == round(e["seconds"] * corpus.RATE)
        assert np.abs(heard).max() > 0 and np.abs(clean).max() > 0
        assert 0.85 <= e["augment"]["tempo"] <= 1.2
        identity = int(e["speaker"].rsplit("-", 1)[1])
        assert e["heldout"] == (e["voice"] == HELDOUT_VOICE.name or identity == corpus.HELDOUT_IDENTITY)
    assert len({e["id"] for e in entries}) == len(entries)
    assert sorted(p.stem for p in (folder / "audio").iterdir()) == sorted(e["id"] for e in entries)


def test_rerun_resumes_without_redoing_work(tiny):
    folder, options = tiny
    before = manifest(folder)
    stamps = {p.name: p.stat().st_mtime_ns for p in (folder / "audio").iterdir()}

    corpus.build(folder, options)  # complete already: nothing to do
    assert manifest(folder) == before
    assert {p.name: p.stat().st_mtime_ns for p in (folder / "audio").iterdir()} == stamps

    # A run killed after the last wav was written but before its manifest line (cut mid-line).
    lines = (folder / corpus.MANIFEST).read_text().splitlines(keepends=True)
    (folder / corpus.MANIFEST).write_text("".join(lines[:-1]) + lines[-1][:10])
    corpus.build(folder, options)
    assert manifest(folder) == before
    assert {p.name: p.stat().st_mtime_ns for p in (folder / "audio").iterdir()} == stamps

    # More hours: the first utterances stay as they were, new ones follow.
    corpus.build(folder, replace(options, hours=TINY_HOURS * 1.5))
    grown = manifest(folder)
    assert grown[: len(before)] == before and len(grown) > len(before)
    assert all(stamps[name] == (folder / "audio" / name).stat().st_mtime_ns for name in stamps)


def test_same_seed_builds_the_same_corpus_whatever_the_jobs(tiny, tmp_path):
    folder, options = tiny
    again = corpus.build(tmp_path / "again", replace(options, jobs=2))
    first = manifest(folder)
    second = manifest(again)
    assert second == first[: len(second)]
    assert sorted(p.stem for p in (again / "clean").iterdir()) == [e["id"] for e in second]  # none rendered ahead left
    name = f"{first[0]['id']}.wav"
    np.testing.assert_array_equal(read_wav(folder / "audio" / name), read_wav(again / "audio" / name))


def test_festival_gives_its_own_phone_times_tiling_its_speech():
    if not (corpus.engine_available("festival") and corpus.festival_has("kal_diphone")):
        pytest.skip("festival's kal_diphone voice is not installed")
    samples, phones = corpus.festival_timed("kal_diphone", "Bob met my mother by the pool.")
    duration = len(samples) / corpus.RATE
    assert duration > 1.0 and phones[0].start == 0.0 and phones[-1].end == pytest.approx(duration)
    assert all(a.end == b.start for a, b in pairwise(phones))
    assert {p.phone for p in phones} <= set(PHONES) | {SILENCE}
    assert [p.phone for p in phones if p.phone != SILENCE][:3] == ["B", "AA", "B"]


def test_sample_texts_follow_the_seed():
    texts = corpus.sample_texts(8)
    assert len(set(texts)) == 8 and texts == corpus.sample_texts(8) and texts != corpus.sample_texts(8, seed=1)
