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

The acoustic model and dictionary ship in the pocketsphinx wheel (US English, CMU ARPAbet without
stress marks, 39 phones + SIL).
"""
import functools
import re
from dataclasses import dataclass

import numpy as np
from pocketsphinx import Decoder

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
class Phone:
    """One aligned phone."""

    phone: str  # CMU ARPAbet without stress ("AA", "P", ...), or SIL
    start: float  # seconds from the start of the audio
    end: float  # seconds; the next phone starts here


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

    def _decoder(self, attempt: int) -> Decoder:
        while len(self.decoders) <= attempt:
            settings = SEARCHES[len(self.decoders)]
            self.decoders.append(Decoder(samprate=SAMPLE_RATE, bestpath=False, loglevel="FATAL", **settings))
        return self.decoders[attempt]

    def align(self, samples: np.ndarray, text: str) -> list[Phone]:
        """Phones of `text` spoken in `samples`, tiling [0, len(samples) / SAMPLE_RATE] without gaps.

        samples: (N,) float32 mono in [-1, 1] at SAMPLE_RATE (16 kHz).
        Raises PuppetError if the transcript is empty or cannot be aligned to the audio.
        """
        words = normalise(text)
        if not words:
            raise PuppetError(f"nothing to align: the transcript {text!r} has no words")
        duration = len(samples) / SAMPLE_RATE
        raw = _padded_pcm(samples)
        for attempt in range(len(SEARCHES)):
            decoder = self._decoder(attempt)
            try:
                aligned = _align(decoder, words, raw)
                break
            except RuntimeError as error:
                reason = error
        else:
            raise PuppetError(f"cannot align {duration:.2f} s of audio to {text[:60]!r}: {reason}")
        hop = SAMPLE_RATE // int(decoder.config["frate"])  # samples per frame

        def seconds(frame):  # into the unpadded audio
            return (frame * hop - PAD_SAMPLES) / SAMPLE_RATE

        return _tile([(_phone_name(name), seconds(start), seconds(end)) for name, start, end in aligned], duration)


def _align(decoder: Decoder, words: list[str], raw: bytes) -> list[tuple[str, int, int]]:
    """(phone, start frame, end frame) of the words in 16-bit PCM; RuntimeError if they do not fit."""
    for word in words:
        if decoder.lookup_word(word) is None:
            decoder.add_word(word, guess_pronunciation(word), True)
    decoder.set_align_text(" ".join(words))
    _decode(decoder, raw)
    if decoder.hyp() is None:
        raise RuntimeError("no alignment path reaches the end of the audio")
    decoder.set_alignment()
    _decode(decoder, raw)
    aligned = [(phone.name, phone.start, phone.start + phone.duration)
               for word in decoder.get_alignment() for phone in word]
    if not aligned:
        raise RuntimeError("no phones")
    return aligned


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
