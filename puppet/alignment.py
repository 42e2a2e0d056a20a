"""Phone-level forced alignment of speech to its transcript, with pocketsphinx.

Sketch: the transcript is normalised to dictionary words (lower case, digits spelled out,
punctuation dropped); a word missing from the CMU dictionary gets a pronunciation guessed from
its letters (`guess_pronunciation`) and is added to the decoder. pocketsphinx then aligns in two
passes over the same 16-bit samples: a word alignment (`set_align_text`: the words in order, each
pronunciation variant and optional silence between words allowed), then a phone alignment of that
word sequence (`set_alignment`). The audio is padded with quiet noise so that it starts and ends
in silence, as the aligner's grammar requires; if no path through the words fits the audio, the
alignment is retried with 5 ms frames instead of 10 ms (`SEARCHES`). The phones' frames are
turned into seconds, silences are labelled SIL, and holes and the tail up to the end of the
audio are filled with SIL, so the phones tile [0, duration] exactly.

Subtitles bring their own times: `align_cues` aligns each cue's words only within its own
stretch of audio (a little beyond it where the neighbouring cues leave room), so a line that was
cut, ad-libbed or mistimed upsets that cue alone, not the rest of a long narration.

Forced alignment fits any words to any audio. `align_checked` also says where they fit badly: a
free phone loop (any phone may follow any, as in the "allphone" search) decodes the same audio,
and wherever the transcript's acoustic score, averaged over FIT_WINDOW_SECONDS, falls more than
POOR_FIT below the loop's, the words there are unlikely to be the ones spoken.

A script that skips a line, or a speaker who ad-libs one, throws a whole-text alignment off from
there on. So when the whole text fits poorly (or not at all), it is anchored instead, as long-audio
aligners do (Moreno et al. 1998; Gentle): the audio is recognised with a language model made of the
script's own word pairs (`script_language_model`), the words heard are matched to the script in
order (`common_runs`), and every run of ANCHOR_WORDS or more agreeing words pins its stretch of the
script to its stretch of audio. Those stretches, and the script between them, are then aligned as
timed cues, like subtitles; script words that fall where no audio is left were not said, and
speech heard where the script has no words is reported as a poor fit. A recogniser that knows only
the script's words finds some of them in any speech, so a script is anchored only if at least
ANCHORED_SHARE of its words are pinned; otherwise the whole alignment stands. Long audio is anchored
whether or not it fits: a forced alignment's memory grows with the square of its length.

With no script at all, `heard` recognises the words with the wheel's general US English language
model (as Rhubarb Lip Sync does) and aligns those, each run between pauses as a timed cue: a
recogniser's words are often wrong, but mostly by sound-alikes ("guess would" for "Dashwood"), and
the mouth needs only their phones.

The acoustic model and dictionary ship in the pocketsphinx wheel (US English, CMU ARPAbet without
stress marks, 39 phones + SIL).
"""
import functools
import math
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pocketsphinx import Decoder, get_model_path

from puppet.errors import PuppetError

SAMPLE_RATE = 16000  # Hz: the acoustic model's rate; `align` takes samples at this rate
SILENCE = "SIL"
# The 39 phones of CMU ARPAbet (without stress), as the acoustic model names them.
PHONES = ("AA", "AE", "AH", "AO", "AW", "AY", "B", "CH", "D", "DH", "EH", "ER", "EY", "F", "G",
          "HH", "IH", "IY", "JH", "K", "L", "M", "N", "NG", "OW", "OY", "P", "R", "S", "SH", "T",
          "TH", "UH", "UW", "V", "W", "Y", "Z", "ZH")
MIN_PHONE_SECONDS = 1e-4  # phones shorter than this after trimming to the audio are dropped
# Quiet noise added before and after the audio, so that the aligner always has silence to start
# and end on (clips that stop dead, as synthetic speech does, fail to align without it).
PAD_SAMPLES = 2400  # 0.15 s
PAD_NOISE = 1e-4  # standard deviation of that noise, full scale 1.0 (-80 dBFS): no digital zeros
# Decoder settings tried in turn. Search beams far wider than pocketsphinx's defaults (1e-48) cost
# little in alignment and let unusual (e.g. synthetic) voices through; 5 ms frames then fit
# phones shorter than the acoustic model's 3 states of 10 ms each, as in very fast speech.
WIDE_BEAMS = {"beam": 1e-120, "pbeam": 1e-120, "wbeam": 1e-100}
SEARCHES = (WIDE_BEAMS, {**WIDE_BEAMS, "frate": 200})
PHONE_LOOP = Path(get_model_path("en-us")) / "en-us-phone.lm.bin"  # the free phone loop's phone bigrams
# The transcript-fit check (see align_checked). Scores are pocketsphinx's acoustic log-likelihoods
# (log base 1.0001) per second of audio, averaged over FIT_WINDOW_SECONDS. With the right words
# (four real readers, the demo, 40 held-out synthetic voices with noise and reverberation added)
# the worst window trails the free loop by 870 to 4,900; with another utterance's words, by 3,500
# to 12,800 (29 of 35 beyond POOR_FIT; 10 more did not align at all). Swapping one sentence of the
# demo for other words is found at the swap.
FIT_WINDOW_SECONDS = 1.0
POOR_FIT = -5500.0
CUE_MARGIN = 0.5  # seconds: a subtitle's words are looked for this far beyond its times, short of the neighbouring cues'
# Anchoring a script that fits poorly (see the module docstring). The recogniser's language model
# gives a script word's successors in the script SCRIPT_FOLLOWS of the probability; the rest goes to
# any script word. Its beams are narrower than alignment's: recognition searches far more paths.
ANCHOR_WORDS = 3  # a run of this many words heard as in the script pins it to the audio
ANCHORED_SHARE = 0.5  # a script is anchored only if at least this share of its words is pinned
SCRIPT_FOLLOWS = 0.9
RECOGNITION_BEAMS = {"beam": 1e-60, "pbeam": 1e-60, "wbeam": 1e-40}
# Script words between anchors are looked for in the audio between them only if it is long enough
# for them (WORD_SECONDS a word) and not far wordier: more than UNSCRIPTED_RATIO times as many
# words (and 2) heard there is speech the script lacks, where its few words cannot be placed.
WORD_SECONDS = 0.1
UNSCRIPTED_RATIO = 2
# Forced alignment holds every frame × every state of the words it aligns at once, so its memory
# grows with the square of the audio's length (6 minutes of read speech in one piece: 3.2 GB).
# Audio longer than LONG_AUDIO_SECONDS is therefore anchored first (its runs of pinned words cut
# into cues of at most MAX_CUE_SECONDS), and recognised words are aligned as cues that end at a
# pause of HEARD_PAUSE between words or at MAX_CUE_SECONDS.
LONG_AUDIO_SECONDS = 120.0
MAX_CUE_SECONDS = 20.0
HEARD_PAUSE = 0.25

# Letter groups → phones, tried longest first, for words the dictionary lacks.
GRAPHEMES = {
    "tion": "SH AH N", "sion": "ZH AH N", "ough": "AO", "augh": "AO", "igh": "AY", "tch": "CH",
    "ch": "CH", "sh": "SH", "th": "TH", "ph": "F", "ng": "NG", "ck": "K", "qu": "K W", "wh": "W",
    "gh": "G", "kn": "N", "wr": "R", "ee": "IY", "ea": "IY", "ie": "IY", "oo": "UW", "ou": "AW",
    "ow": "OW", "oi": "OY", "oy": "OY", "ai": "EY", "ay": "EY", "au": "AO", "aw": "AO", "ey": "EY",
    "er": "ER", "ir": "ER", "ur": "ER", "ar": "AA R", "or": "AO R",
    "a": "AE", "b": "B", "c": "K", "d": "D", "e": "EH", "f": "F", "g": "G", "h": "HH", "i": "IH",
    "j": "JH", "k": "K", "l": "L", "m": "M", "n": "N", "o": "AA", "p": "P", "q": "K", "r": "R",
    "s": "S", "t": "T", "u": "AH", "v": "V", "w": "W", "x": "K S", "y": "IY", "z": "Z",
}
GRAPHEME_MAX = max(map(len, GRAPHEMES))  # 4: the longest letter group

ONES = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten", "eleven",
        "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen", "nineteen")
TENS = ("", "", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety")  # by tens digit
SCALES = ((10**9, "billion"), (10**6, "million"), (1000, "thousand"), (100, "hundred"))
SYMBOLS = {"&": " and ", "%": " percent ", "+": " plus ", "@": " at "}


@dataclass(frozen=True)
class Cue:
    """One subtitle: words said between two times."""

    start: float  # seconds from the start of the audio
    end: float
    text: str


@dataclass(frozen=True)
class Phone:
    """One aligned phone."""

    phone: str  # CMU ARPAbet without stress ("AA", "P", ...), or SIL
    start: float  # seconds from the start of the audio
    end: float  # seconds; the next phone starts here


@dataclass(frozen=True)
class Alignment:
    """Words placed in audio, and where not to trust them."""

    phones: list[Phone]  # tiling [0, duration] of the audio
    misfits: list[tuple[float, float]]  # (start, end) seconds where the words fit the audio poorly
    unsaid: list[tuple[float, float]]  # (start, end) seconds no words were given for (outside every subtitle cue)


def number_words(n: int) -> str:
    """English words for a non-negative integer: 1984 → "one thousand nine hundred eighty four"."""
    if n < 20:
        return ONES[n]
    if n < 100:
        return TENS[n // 10] + ("" if n % 10 == 0 else " " + ONES[n % 10])
    for size, name in SCALES:
        if n >= size:
            rest = "" if n % size == 0 else " " + number_words(n % size)
            return f"{number_words(n // size)} {name}{rest}"
    raise AssertionError("unreachable")


def normalise(text: str) -> list[str]:
    """Lower-case dictionary-style words of a transcript: "It's 3 a.m.!" → ["it's", "three", "a", "m"]."""
    for symbol, words in SYMBOLS.items():
        text = text.replace(symbol, words)
    text = re.sub(r"\d+", lambda match: " " + number_words(int(match.group())) + " ", text.lower())
    text = re.sub(r"[^a-z']+", " ", text)
    return [word.strip("'") for word in text.split() if word.strip("'")]


def guess_pronunciation(word: str) -> str:
    """ARPAbet phones guessed from a word's letters (for names and coinages the dictionary lacks)."""
    letters = word.lower().replace("'", "")
    if len(letters) > 2 and letters.endswith("e") and letters[-2] not in "aeiouy":
        letters = letters[:-1]  # a silent final e
    phones, i = [], 0
    while i < len(letters):
        for size in range(min(GRAPHEME_MAX, len(letters) - i), 0, -1):
            chunk = letters[i:i + size]
            if chunk in GRAPHEMES:
                if not (phones and size == 1 and i > 0 and letters[i - 1] == chunk):  # doubled letters
                    phones.extend(GRAPHEMES[chunk].split())
                i += size
                break
        else:
            i += 1  # not a letter we know
    if not phones:
        raise PuppetError(f"cannot guess how to pronounce {word!r} for alignment")
    return " ".join(phones)


class Aligner:
    """Owns pocketsphinx decoders (loading the model takes about a second each); reuse it.

    Each utterance is tried with the decoders of SEARCHES in turn until one aligns it.
    """

    def __init__(self):
        self.decoders: list[Decoder] = []  # made on first need, one per entry of SEARCHES
        self.phone_loops: list[Decoder] = []  # the same, searching a free phone loop
        self.recogniser: Decoder | None = None  # recognises a script's words, to anchor it (made on first need)
        self.listener: Decoder | None = None  # recognises any English words, for `heard` (made on first need)

    def _decoder(self, attempt: int, phone_loop: bool = False) -> Decoder:
        decoders = self.phone_loops if phone_loop else self.decoders
        while len(decoders) <= attempt:
            settings = SEARCHES[len(decoders)] | ({"allphone": str(PHONE_LOOP)} if phone_loop else {"bestpath": False})
            decoders.append(Decoder(samprate=SAMPLE_RATE, loglevel="FATAL", **settings))
        return decoders[attempt]

    def align(self, samples: np.ndarray, text: str) -> list[Phone]:
        """Phones of `text` spoken in `samples`, tiling [0, len(samples) / SAMPLE_RATE] without gaps.

        samples: (N,) float32 mono in [-1, 1] at SAMPLE_RATE (16 kHz).
        Raises PuppetError if the transcript is empty or cannot be aligned to the audio.
        """
        aligned, attempt = self._forced(samples, text)
        return self._phones(aligned, attempt, len(samples) / SAMPLE_RATE)

    def align_checked(self, samples: np.ndarray, text: str) -> Alignment:
        """The phones of `text` in `samples` and the stretches of audio where the words fit poorly:
        spoken differently or not at all, or words spoken that the text lacks. Aligned whole, or, if
        that fits poorly or fails, anchored on the runs of words recognised as in the script (module
        docstring; audio longer than LONG_AUDIO_SECONDS is anchored first, to bound memory);
        PuppetError if neither places any words."""
        if len(samples) / SAMPLE_RATE > LONG_AUDIO_SECONDS:
            anchored = self._anchored(samples, text)
            if anchored is not None:
                return anchored
        try:
            whole = self._checked(samples, text)
            if not whole.misfits:
                return whole
        except PuppetError:
            whole = None
        anchored = self._anchored(samples, text)
        if anchored is not None:
            return anchored
        return whole or self._checked(samples, text)  # the last raises the whole alignment's error

    def _checked(self, samples: np.ndarray, text: str) -> Alignment:
        """The whole text's alignment and where it fits poorly (see align_checked)."""
        aligned, attempt = self._forced(samples, text)
        duration = len(samples) / SAMPLE_RATE
        loop = self._decoder(attempt, phone_loop=True)
        _decode(loop, _padded_pcm(samples))
        free = [(segment.start_frame, segment.end_frame + 1, loop.get_logmath().log(segment.ascore)) for segment in loop.seg()]
        spans = _poor_fits([(start, end, score) for _, start, end, score in aligned], free, int(loop.config["frate"]))
        misfits = [(max(self._seconds(attempt, start), 0.0), min(self._seconds(attempt, end), duration)) for start, end in spans]
        return Alignment(self._phones(aligned, attempt, duration), [(start, end) for start, end in misfits if end > start], [])

    def align_cues(self, samples: np.ndarray, cues: tuple[Cue, ...]) -> Alignment:
        """`align_checked` for subtitles: each cue's words aligned within its own times (CUE_MARGIN
        beyond them where its neighbours leave room); a cue that cannot be aligned there is a poor
        fit over its whole stretch, and the audio outside every cue is unsaid."""
        duration = len(samples) / SAMPLE_RATE
        cues = sorted((cue for cue in cues if normalise(cue.text)), key=lambda cue: cue.start)
        spoken, misfits, unsaid, said_until = [], [], [], 0.0
        for i, cue in enumerate(cues):
            start = max(cue.start - CUE_MARGIN, said_until)
            end = min(cue.end + CUE_MARGIN, cues[i + 1].start if i + 1 < len(cues) else duration, duration)
            if end - start < FIT_WINDOW_SECONDS / 10:
                continue  # a cue wholly outside the audio, or inside the one before
            if start - said_until > MIN_PHONE_SECONDS:
                unsaid.append((said_until, start))
            said_until = end
            window = samples[round(start * SAMPLE_RATE):round(end * SAMPLE_RATE)]
            try:
                aligned = self._checked(window, cue.text)
            except PuppetError:
                misfits.append((start, end))
                continue
            spoken += [(p.phone, start + p.start, start + p.end) for p in aligned.phones if p.phone != SILENCE]
            misfits += [(start + a, start + b) for a, b in aligned.misfits]
        if duration - said_until > MIN_PHONE_SECONDS:
            unsaid.append((said_until, duration))
        return Alignment(_tile(spoken, duration), misfits, unsaid)

    def heard(self, samples: np.ndarray) -> Alignment | None:
        """The words recognised in `samples` (US English language model), aligned in runs between
        pauses as timed cues (see `align_cues`: audio outside every run is unsaid); None where no words are heard."""
        if self.listener is None:
            self.listener = Decoder(samprate=SAMPLE_RATE, loglevel="FATAL")
        _decode(self.listener, _padded_pcm(samples))
        words = [(word, start, end) for word, start, end in _words(self.listener) if not word.startswith(("<", "["))]  # no silences or noises
        if not words:
            return None
        runs = [[words[0]]]
        for word in words[1:]:
            if word[1] - runs[-1][-1][2] >= HEARD_PAUSE or word[1] - runs[-1][0][1] >= MAX_CUE_SECONDS:
                runs.append([])
            runs[-1].append(word)
        return self.align_cues(samples, tuple(Cue(run[0][1], run[-1][2], " ".join(word for word, _, _ in run)) for run in runs))

    def _anchored(self, samples: np.ndarray, text: str) -> Alignment | None:
        """The script aligned between its anchors (module docstring), or None where too few of its
        words are heard as in the script to pin it (under ANCHORED_SHARE in runs of ANCHOR_WORDS)."""
        words = normalise(text)
        if not words:
            return None
        heard = self._recognise(samples, words)
        runs = [run for run in common_runs(words, [word for word, _, _ in heard]) if run[2] >= ANCHOR_WORDS]
        if not runs or sum(size for _, _, size in runs) < ANCHORED_SHARE * len(words):
            return None  # not this script, mostly: a recogniser that knows only its words finds some anyway
        duration = len(samples) / SAMPLE_RATE
        cues, unscripted, said, heard_until, until = [], [], 0, 0, 0.0
        for in_script, in_heard, size in [*runs, (len(words), len(heard), 0)]:
            start = heard[in_heard][1] if size else duration
            between = words[said:in_script]  # script words between the anchors
            if between and start - until >= WORD_SECONDS * len(between) and in_heard - heard_until <= UNSCRIPTED_RATIO * len(between) + 2:
                cues.append(Cue(until, start, " ".join(between)))
            elif in_heard > heard_until:  # speech where the script has nothing (left)
                unscripted.append((heard[heard_until][1], heard[in_heard - 1][2]))
            piece = 0  # the run cut into cues of at most MAX_CUE_SECONDS
            for end in range(1, size + 1):
                if end == size or heard[in_heard + end][2] - heard[in_heard + piece][1] > MAX_CUE_SECONDS:
                    cues.append(Cue(heard[in_heard + piece][1], heard[in_heard + end - 1][2], " ".join(words[in_script + piece:in_script + end])))
                    piece = end
            if size:
                said, heard_until, until = in_script + size, in_heard + size, cues[-1].end
        aligned = self.align_cues(samples, tuple(cues))
        return Alignment(aligned.phones, sorted(aligned.misfits + unscripted), aligned.unsaid)

    def _recognise(self, samples: np.ndarray, words: list[str]) -> list[tuple[str, float, float]]:
        """(word, start, end seconds) of each word recognised in the samples by a decoder that knows only the script's words."""
        if self.recogniser is None:
            self.recogniser = Decoder(samprate=SAMPLE_RATE, loglevel="FATAL", **RECOGNITION_BEAMS)
        decoder, vocabulary = self.recogniser, set(words)
        for word in vocabulary:
            if decoder.lookup_word(word) is None:
                decoder.add_word(word, guess_pronunciation(word), True)
        with tempfile.NamedTemporaryFile("w", suffix=".arpa") as model:
            model.write(script_language_model(words))
            model.flush()
            decoder.add_lm_file("script", model.name)
        decoder.activate_search("script")
        _decode(decoder, _padded_pcm(samples))
        return [(word, start, end) for word, start, end in _words(decoder) if word in vocabulary]

    def _forced(self, samples: np.ndarray, text: str) -> tuple[list[tuple[str, int, int, float]], int]:
        """(_align's phones, the index of the SEARCHES entry that aligned them); PuppetError if none does."""
        words = normalise(text)
        if not words:
            raise PuppetError(f"nothing to align: the transcript {text!r} has no words")
        raw = _padded_pcm(samples)
        for attempt in range(len(SEARCHES)):
            try:
                return _align(self._decoder(attempt), words, raw), attempt
            except RuntimeError as error:
                reason = error
        raise PuppetError(f"cannot align {len(samples) / SAMPLE_RATE:.2f} s of audio to {' '.join(text.split())[:60]!r}: {reason}; "
                          "are those the words spoken? (Loud music or noise under the voice can also defeat the aligner)")

    def _seconds(self, attempt: int, frame: int) -> float:
        """Seconds into the unpadded audio of a frame of SEARCHES[attempt]'s decode of the padded audio."""
        return _frame_seconds(self._decoder(attempt), frame)

    def _phones(self, aligned: list[tuple[str, int, int, float]], attempt: int, duration: float) -> list[Phone]:
        """_align's phones as Phones tiling [0, duration] seconds."""
        return _tile([(_phone_name(name), self._seconds(attempt, start), self._seconds(attempt, end))
                      for name, start, end, _ in aligned], duration)


def common_runs(script: list[str], heard: list[str]) -> list[tuple[int, int, int]]:
    """(index in script, index in heard, length) of the runs of consecutive words that a longest
    common subsequence of the two word lists pairs up, in order, each pair as early in both as a
    longest one allows. Unlike a greedy longest-block match, it is not misled by repeated lines."""
    ids = {word: i for i, word in enumerate(set(script) | set(heard))}
    same = np.array([ids[w] for w in script], np.int64)[:, None] == np.array([ids[w] for w in heard], np.int64)[None, :]
    longest = np.zeros((len(script) + 1, len(heard) + 1), np.int32)  # over script[i:], heard[j:]
    for i in range(len(script) - 1, -1, -1):
        step = np.maximum(longest[i + 1, :-1], longest[i + 1, 1:] + same[i])
        longest[i, :-1] = np.maximum.accumulate(step[::-1])[::-1]
    runs: list[list[int]] = []
    i = j = 0
    while i < len(script) and j < len(heard):
        if same[i, j] and longest[i, j] == longest[i + 1, j + 1] + 1:
            if runs and runs[-1][0] + runs[-1][2] == i and runs[-1][1] + runs[-1][2] == j:
                runs[-1][2] += 1
            else:
                runs.append([i, j, 1])
            i, j = i + 1, j + 1
        elif longest[i, j + 1] >= longest[i + 1, j]:
            j += 1
        else:
            i += 1
    return [(a, b, size) for a, b, size in runs]


def script_language_model(words: list[str]) -> str:
    """An ARPA bigram language model of a script's words: each word is followed by its successors in
    the script (SCRIPT_FOLLOWS of the probability, shared equally) or, backing off, by any word of
    the script; the script starts with its first word and ends after its last."""
    vocabulary = sorted(set(words)) + ["</s>"]
    follows: dict[str, set[str]] = {}
    for before, after in zip(["<s>", *words], [*words, "</s>"]):
        follows.setdefault(before, set()).add(after)
    unigram = 1.0 / len(vocabulary)

    def backoff(word: str) -> float:
        return math.log10((1.0 - SCRIPT_FOLLOWS) / max(1.0 - unigram * len(follows[word]), unigram)) if word in follows else 0.0

    lines = ["\\data\\", f"ngram 1={len(vocabulary) + 1}", f"ngram 2={sum(map(len, follows.values()))}", "",
             "\\1-grams:", f"-99 <s> {backoff('<s>'):.4f}"]
    lines += [f"{math.log10(unigram):.4f} {word} {backoff(word):.4f}" for word in vocabulary]
    lines += ["", "\\2-grams:"]
    lines += [f"{math.log10(SCRIPT_FOLLOWS / len(after)):.4f} {before} {word}" for before, after in follows.items() for word in sorted(after)]
    return "\n".join([*lines, "", "\\end\\", ""])


def _poor_fits(aligned: list[tuple[int, int, float]], free: list[tuple[int, int, float]], frame_rate: int) -> list[tuple[int, int]]:
    """[start, end) frame runs where the forced alignment's acoustic score, averaged over a window of
    FIT_WINDOW_SECONDS, trails the free phone loop's by more than POOR_FIT per second; runs less
    than a window apart are merged.

    aligned, free: (start frame, end frame, acoustic score) of each phone of either decode.
    """
    frames = max(end for _, end, _ in aligned + free)
    deficit = np.zeros(frames)
    for spans, sign in ((aligned, 1.0), (free, -1.0)):
        for start, end, score in spans:
            if end > start:
                deficit[start:end] += sign * score / (end - start)
    window = round(FIT_WINDOW_SECONDS * frame_rate)
    per_second = np.convolve(deficit, np.full(window, frame_rate / window), mode="same")
    poor = np.r_[False, per_second < POOR_FIT, False]
    runs: list[tuple[int, int]] = []
    for start, end in np.flatnonzero(poor[1:] != poor[:-1]).reshape(-1, 2).tolist():
        if runs and start - runs[-1][1] < window:
            start = runs.pop()[0]
        runs.append((start, end))
    return runs


def _align(decoder: Decoder, words: list[str], raw: bytes) -> list[tuple[str, int, int, float]]:
    """(phone, start frame, end frame, acoustic score) of the words in 16-bit PCM; RuntimeError if they do not fit."""
    for word in words:
        if decoder.lookup_word(word) is None:
            decoder.add_word(word, guess_pronunciation(word), True)
    decoder.set_align_text(" ".join(words))
    _decode(decoder, raw)
    if decoder.hyp() is None:
        raise RuntimeError("no alignment path reaches the end of the audio")
    decoder.set_alignment()
    _decode(decoder, raw)
    aligned = [(phone.name, phone.start, phone.start + phone.duration, phone.score)
               for word in decoder.get_alignment() for phone in word]
    if not aligned:
        raise RuntimeError("no phones")
    return aligned


def _words(decoder: Decoder) -> list[tuple[str, float, float]]:
    """(word, start, end seconds into the unpadded audio) of each segment of the decoder's last pass,
    pronunciation variants named as their word ("the(2)" → "the")."""
    return [(segment.word.split("(")[0], _frame_seconds(decoder, segment.start_frame), _frame_seconds(decoder, segment.end_frame + 1))
            for segment in decoder.seg()]


def _frame_seconds(decoder: Decoder, frame: int) -> float:
    """Seconds into the unpadded audio of a frame of the decoder's pass over the padded audio."""
    hop = SAMPLE_RATE // int(decoder.config["frate"])  # samples per frame
    return (frame * hop - PAD_SAMPLES) / SAMPLE_RATE


def _decode(decoder: Decoder, raw: bytes) -> None:
    """One pass over the whole utterance, from a fresh feature state (cepstral mean, noise
    estimate), so that an alignment never depends on what the decoder heard before."""
    decoder.reinit_feat()
    decoder.start_utt()
    decoder.process_raw(raw, full_utt=True)
    decoder.end_utt()


def _padded_pcm(samples: np.ndarray) -> bytes:
    """16-bit PCM of the samples with PAD_SAMPLES of quiet noise before and after."""
    pad = np.random.default_rng(0).normal(0.0, PAD_NOISE, PAD_SAMPLES).astype(np.float32)
    signal = np.concatenate([pad, np.nan_to_num(np.asarray(samples, np.float32)), pad])
    return (np.clip(signal, -1.0, 1.0) * 32767).astype(np.int16).tobytes()


def _phone_name(name: str) -> str:
    """ARPAbet name without stress; fillers and noise are silence for the face."""
    name = name.rstrip("012")
    return name if name in PHONES else SILENCE


def _tile(aligned: list[tuple[str, float, float]], duration: float) -> list[Phone]:
    """Phones trimmed to [0, duration], holes filled with SIL, neighbouring silences merged."""
    phones: list[Phone] = []

    def put(name, start, end):
        start, end = max(start, phones[-1].end if phones else 0.0), min(end, duration)
        if end - start < MIN_PHONE_SECONDS:
            return
        if phones and phones[-1].phone == name == SILENCE:
            phones[-1] = Phone(SILENCE, phones[-1].start, end)
        else:
            phones.append(Phone(name, start, end))

    for name, start, end in aligned:
        if end <= 0.0:
            continue  # in the padding
        if start > (phones[-1].end if phones else 0.0) + MIN_PHONE_SECONDS:
            put(SILENCE, phones[-1].end if phones else 0.0, start)
        put(name, start, end)
    put(SILENCE, phones[-1].end if phones else 0.0, duration)
    if phones:  # the last phone ends with the audio, even if it was a hair short
        phones[-1] = Phone(phones[-1].phone, phones[-1].start, duration)
    return phones


@functools.cache
def _default_aligner() -> Aligner:
    return Aligner()


def align(samples: np.ndarray, text: str) -> list[Phone]:
    """Phones of `text` in (N,) float32 16 kHz `samples`, tiling the audio; see `Aligner.align`.

    Uses one decoder per process, loaded on first use.
    """
    return _default_aligner().align(samples, text)


def align_checked(samples: np.ndarray, words: str | tuple[Cue, ...]) -> Alignment:
    """`words` (a transcript, or timed subtitle cues) placed in (N,) float32 16 kHz `samples`; see
    `Aligner.align_checked` and `Aligner.align_cues`."""
    if isinstance(words, str):
        return _default_aligner().align_checked(samples, words)
    return _default_aligner().align_cues(samples, words)


def heard(samples: np.ndarray) -> Alignment | None:
    """The words recognised in (N,) float32 16 kHz `samples`, aligned; see `Aligner.heard`."""
    return _default_aligner().heard(samples)
