"""Lip sync from the learned predictor: speech → the network's canonical motion → this face.

The network (puppet.predictor) hears the voice and its speaker embedding (puppet.speaker) and
gives landmark offsets in face units at MOTION_FPS plus a head rotation; here they are scaled and
turned onto the portrait's own face (q + Δq, as in MakeItTalk) and resampled to the video's rate.
The live window uses the streaming model, which hears 60 ms ahead. Files use it together with the
offline one, which hears 300 ms ahead (the paper's content window): the two were trained apart and
err differently, and their mean is closer to the truth than either on every measure (model card).

Pauses. The network rests the mouth in digital silence, but a real recording's pauses hold room tone,
hiss and breath, over which it leaves the lips a little apart. A file is known whole, so its pauses are
found from its own levels (the live window has its noise gate instead, puppet.live.VoiceGate): a run of
at least PAUSE_SECONDS whose 20 ms frames all lie PAUSE_BELOW_DB under the recording's loud speech
(its SPEECH_PERCENTILE frame), or, in a noisy recording, close to its noise floor, is a pause, and
the mouth and brows ease to rest inside it over PAUSE_EASE_SECONDS from each end, head motion untouched.

Transcripts. When the words spoken are known (a script, subtitles), the aligner (puppet.alignment)
places their phones in the audio and the articulation model (puppet.visemes) that made the network's
training targets moves the jaw and lips from them directly: every p/b/m closes, every "oo" rounds,
on time, whatever the voice. Brows, eyes and head still come from the network.

Recognised words. With no script, the words can be recognised in the audio (puppet.alignment.heard,
pocketsphinx's English language model) and their phones aligned and articulated the same way. The
recogniser also hears words in music or noise where nobody speaks; the network does not (its voice
detector), so wherever the network's jaw and lips stay within STILL_TOLERANCE of rest for
PAUSE_SECONDS or more, the mouth stays the network's.
"""
import functools
import re
import warnings
from pathlib import Path

import numpy as np
from scipy import ndimage

from puppet import speaker
from puppet.alignment import Alignment, Cue, align_checked, heard
from puppet.errors import PuppetError, PuppetWarning
from puppet.features import MOTION_FPS, SAMPLE_RATE, motion_frame_count
from puppet.landmarks import JAW, MOUTH, from_face_units
from puppet.motion import Motion, resample
from puppet.predictor import MODEL_FILES, Ensemble, Predictor, default_model
from puppet.visemes import frame_times, mouth_motion


@functools.cache
def shipped_predictor(kind: str) -> Predictor:
    """A trained model in assets/models, "offline" or "streaming", loaded once."""
    return Predictor(default_model(kind))


@functools.cache
def file_predictor() -> Ensemble:
    """What files are animated with: the offline and streaming models averaged (a file is known
    whole, so the live model's shorter lookahead costs nothing, and the two err differently)."""
    return Ensemble((shipped_predictor("offline"), shipped_predictor("streaming")))


def has_model() -> bool:
    """Whether the trained models ship with this install."""
    return all(default_model(kind).is_file() for kind in MODEL_FILES)


PAUSE_SECONDS = 0.3  # quiet runs shorter than this (stop closures, breaths between words) are speech
PAUSE_BELOW_DB = 20.0  # a frame this far under the loud speech level is quiet
SPEECH_PERCENTILE = 98  # the recording's loud speech level: this percentile of its frame levels
# In a noisy recording (a fan, traffic: the noise floor less than PAUSE_BELOW_DB under the speech) a
# frame within PAUSE_ABOVE_FLOOR_DB of the floor (its FLOOR_PERCENTILE frame) is quiet too, if that is
# still at least PAUSE_MIN_BELOW_DB under the loud speech.
FLOOR_PERCENTILE = 5
PAUSE_ABOVE_FLOOR_DB = 6.0
PAUSE_MIN_BELOW_DB = 8.0
PAUSE_EASE_SECONDS = 0.1  # inside a pause, the offsets fade to rest over this from each end


def pause_weights(samples: np.ndarray) -> np.ndarray:
    """(T,) float32 in [0, 1] per motion frame of (N,) float32 16 kHz mono speech (T = motion_frame_count(N)):
    1 while speaking, easing to 0 inside pauses (see the module docstring)."""
    frames = motion_frame_count(len(samples))
    step = int(SAMPLE_RATE // MOTION_FPS)  # 320 samples, 20 ms
    padded = np.zeros(frames * step, np.float32)
    padded[: len(samples)] = samples[: len(padded)]
    level = 10 * np.log10(np.mean(padded.reshape(frames, step) ** 2, axis=1) + 1e-12)  # dBFS per frame
    loud, floor = np.percentile(level, SPEECH_PERCENTILE), np.percentile(level, FLOOR_PERCENTILE)
    threshold = max(loud - PAUSE_BELOW_DB, min(floor + PAUSE_ABOVE_FLOOR_DB, loud - PAUSE_MIN_BELOW_DB))
    quiet = np.r_[False, level < threshold, False]
    edges = np.flatnonzero(quiet[1:] != quiet[:-1]).reshape(-1, 2)  # [start, end) of each quiet run
    weights = np.ones(frames, np.float32)
    ease = PAUSE_EASE_SECONDS * MOTION_FPS
    for start, end in edges:
        if end - start >= PAUSE_SECONDS * MOTION_FPS:
            t = np.arange(start, end)
            weights[start:end] = 1.0 - np.clip(np.minimum(t - start, end - 1 - t) / ease, 0.0, 1.0)
    return weights


SPOKEN_POINTS = [*JAW, *MOUTH]  # the landmarks a transcript's phones move


SUBTITLE_TAG = re.compile(r"<[^>]*>|\{[^}]*\}|\[[^]]*]|\([^)]*\)|♪")  # <i>, <c.yellow>, {\an8}; [Music], (laughs), ♪
SUBTITLE_TIME = r"(?:(\d+):)?(\d{1,2}):(\d{1,2})[.,](\d{1,3})"  # [hh:]mm:ss,mmm (.srt) or [hh:]mm:ss.mmm (.vtt)
SUBTITLE_TIMING = re.compile(rf"\s*{SUBTITLE_TIME}\s*-->\s*{SUBTITLE_TIME}")
MISFITS_NAMED = 3  # a poorly fitting transcript's warning names this many stretches of audio
MISFIT_EASE = 0.1  # seconds over which the mouth passes between the transcript's and the network's
STILL_TOLERANCE = 0.03  # face units: recognised words do not move a mouth the network holds this close to rest


def read_transcript(path) -> str | tuple[Cue, ...]:
    """The words of a transcript file: plain UTF-8 text as it is, or the cues of subtitles (.srt,
    .vtt): each timing with the text lines under it, styling tags and sound descriptions dropped
    (headers, notes and cue numbers or names are not under a timing)."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as error:
        raise PuppetError(f"cannot read the transcript {path}: {error.strerror}") from None
    except UnicodeDecodeError:
        raise PuppetError(f"the transcript {path} is not UTF-8 text") from None
    if not str(path).lower().endswith((".srt", ".vtt")):
        return text
    cues, lines = [], text.splitlines()
    for i, line in enumerate(lines):
        if "-->" not in line:
            continue
        timing = SUBTITLE_TIMING.match(line)
        if timing is None:
            raise PuppetError(f"cannot read the subtitle timing {line.strip()!r} in {path}")
        fields = timing.groups()
        start, end = _subtitle_seconds(*fields[:4]), _subtitle_seconds(*fields[4:])
        words = []
        for below in lines[i + 1:]:
            if not below.strip() or "-->" in below:
                break
            words.append(SUBTITLE_TAG.sub(" ", below))
        cues.append(Cue(start, end, " ".join(words)))
    if not cues:
        raise PuppetError(f"no subtitle cues (lines like 00:00:01,000 --> 00:00:02,500) in {path}")
    return tuple(cues)


def _subtitle_seconds(hours: str | None, minutes: str, seconds: str, fraction: str) -> float:
    """Seconds of a subtitle time's fields: (None, "01", "02", "5") → 62.5."""
    return int(hours or 0) * 3600 + int(minutes) * 60 + int(seconds) + int(fraction.ljust(3, "0")) / 1000


def spoken_mouth(offsets: np.ndarray, samples: np.ndarray, transcript: str | tuple[Cue, ...]) -> np.ndarray:
    """(T, 68, 3) canonical offsets (face units, MOTION_FPS) with the jaw and lips replaced by the
    articulation of the transcript's phones (plain text, or timed subtitle cues), aligned to (N,)
    float32 16 kHz speech (T = motion_frame_count(N)). Where the words fit the audio poorly (with a
    PuppetWarning), and outside every subtitle cue, the jaw and lips stay the network's, eased in
    and out over MISFIT_EASE."""
    aligned = align_checked(samples, transcript)
    if aligned.misfits:
        named = ", ".join(f"{clock(start)}–{clock(end)}" for start, end in aligned.misfits[:MISFITS_NAMED])
        more = f" and {len(aligned.misfits) - MISFITS_NAMED} more" if len(aligned.misfits) > MISFITS_NAMED else ""
        warnings.warn(PuppetWarning(f"the transcript does not fit the audio at {named}{more}: are those the words spoken? "
                                    "The mouth follows the sound there instead"), stacklevel=2)
    return articulated(offsets, aligned)


def heard_mouth(offsets: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """`spoken_mouth` with the words recognised in the speech instead of a transcript (module
    docstring): (T, 68, 3) canonical offsets for (N,) float32 16 kHz speech; where no words are
    heard, or the network holds the mouth at rest, its offsets are kept."""
    aligned = heard(samples)
    if aligned is None:
        return offsets
    spoken = articulated(offsets, aligned)
    near_rest = np.abs(offsets[:, SPOKEN_POINTS, :2]).max(axis=(1, 2)) < STILL_TOLERANCE
    run = round(PAUSE_SECONDS * MOTION_FPS)
    still = ndimage.maximum_filter1d(ndimage.minimum_filter1d(near_rest.astype(np.float32), run), run)  # runs of `run` frames or more
    still = ndimage.uniform_filter1d(still, round(MISFIT_EASE * MOTION_FPS) | 1)[:, None, None]  # eased in and out
    spoken[:, SPOKEN_POINTS] = still * offsets[:, SPOKEN_POINTS] + (1.0 - still) * spoken[:, SPOKEN_POINTS]
    return spoken


def articulated(offsets: np.ndarray, aligned: Alignment) -> np.ndarray:
    """(T, 68, 3) offsets with the jaw and lips moved by the aligned phones' articulation, except
    where the words fit poorly or were not given (eased over MISFIT_EASE): there they stay the network's."""
    times = frame_times(len(offsets))
    network = np.zeros(len(offsets))  # (T,) share of the network's jaw and lips
    for start, end in aligned.misfits + aligned.unsaid:
        network = np.maximum(network, np.clip(np.minimum(times - start, end - times) / MISFIT_EASE + 1.0, 0.0, 1.0))
    said = mouth_motion(aligned.phones, len(offsets))
    spoken = offsets.copy()
    spoken[:, SPOKEN_POINTS] = network[:, None, None] * offsets[:, SPOKEN_POINTS] + (1.0 - network[:, None, None]) * said[:, SPOKEN_POINTS]
    return spoken


def clock(seconds: float) -> str:
    """m:ss.s: 75.25 → "1:15.2"."""
    minutes, seconds = divmod(round(seconds, 1), 60)
    return f"{int(minutes)}:{seconds:04.1f}"


def speech_offsets(samples: np.ndarray, predictor: Predictor | Ensemble, embedding: np.ndarray | None = None,
                   transcript: str | tuple[Cue, ...] | None = None, recognise: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The network's answer for (N,) float32 16 kHz mono speech, at rest in its pauses: canonical
    offsets (T, 68, 3) in face units and head rotation (T, 3) radians, at MOTION_FPS. embedding: the
    voice's (256,) speaker embedding when already known; transcript: the words spoken, when known
    (the jaw and lips then follow their phones, see spoken_mouth); recognise: without a transcript,
    the jaw and lips follow the phones of the words recognised in the speech (see heard_mouth)."""
    embedding = speaker.embed(samples) if embedding is None else embedding
    offsets, rotation = predictor.predict(samples, embedding, SAMPLE_RATE)
    offsets = offsets * pause_weights(samples)[:, None, None]
    if transcript is not None:
        offsets = spoken_mouth(offsets, samples, transcript)
    elif recognise:
        offsets = heard_mouth(offsets, samples)
    return offsets, rotation


def learned_motion(samples: np.ndarray, rest: np.ndarray, fps: float, frames: int, predictor: Predictor | Ensemble | None = None,
                   transcript: str | tuple[Cue, ...] | None = None, recognise: bool = False) -> Motion:
    """Motion of `frames` frames at `fps` for (N,) float32 16 kHz speech on a face with (68, 3)
    rest landmarks (pixels): mouth and expression offsets and head rotation, no translation.
    transcript, recognise: where the jaw and lips take their phones from, if not from the network
    (see speech_offsets)."""
    offsets, rotation = speech_offsets(samples, predictor or file_predictor(), transcript=transcript, recognise=recognise)
    return Motion(
        offsets=from_face_units(resample(offsets, MOTION_FPS, fps, frames), rest),
        rotation=resample(rotation, MOTION_FPS, fps, frames),
        translation=np.zeros((frames, 2), np.float32),
        fps=fps,
    )
