"""Speech → landmark motion at run time: the exported network (puppet.network) under onnxruntime.

No torch here or in anything this imports. One ONNX file holds the whole network; its metadata says
which audio features it was trained on (checked against puppet.features), its frame rate, landmark
count and lookahead. The network is causal and carries its state explicitly, so `Stream`, fed audio
in chunks of any size, gives the same motion as `Predictor.predict` on the whole clip (to ~1e-5).

Timing of a stream. Motion frame t covers log-mel frames 2t and 2t + 1; the network emits it at
step t + lookahead, once log-mel frame 2(t + lookahead) + 1 is complete, i.e. once
320·t + 320·lookahead + 360 samples have arrived (the Hann window reaches 200 samples past a frame's
centre). With lookahead 3 (the default) that is 82.5 ms of audio past the start of frame t, 72.5 ms
past its centre, 60 ms of which is the network's own lookahead. At the end of the audio, `finish` pads silence to release the last frames.
"""
import json
from concurrent.futures import ThreadPoolExecutor
from importlib.resources import files
from pathlib import Path

import numpy as np
import onnxruntime as ort

from puppet import features
from puppet.errors import PuppetError

# The shipped models, in the puppet.assets package (the repository's assets/): the same network
# trained to hear 60 ms ahead (live) or 300 ms ahead (files, where the whole clip is known).
MODEL_FILES = {"streaming": "models/landmarks.onnx", "offline": "models/landmarks_offline.onnx"}
SPEAKER_DIM = 256  # puppet.speaker.embed's output
N_STEP = features.N_MELS * features.FRAMES_PER_MOTION  # 160 log-mel values per motion step
SILENCE = float(np.log10(features.LOG_FLOOR))  # -5.0: the log-mel of digital silence
WINDOW_REACH = features.WINDOW // 2  # 200 samples: how far past its centre a log-mel frame reads
CONTEXT_FRAMES = -(-(features.N_FFT // 2) // features.HOP)  # 2 frames of samples kept before the next frame
OFFLINE_CHUNK = 200  # motion steps per network run offline (4 s): attention cost grows with chunk², LSTM's not


def default_model(kind: str) -> Path:
    """The trained model shipped with puppet: "streaming" (live) or "offline" (files)."""
    return Path(str(files("puppet.assets") / MODEL_FILES[kind]))


def to_mono_16k(samples: np.ndarray, sample_rate: int = features.SAMPLE_RATE) -> np.ndarray:
    """(N,) or (N, channels) samples at sample_rate → (M,) float32 mono at 16 kHz (polyphase resampling)."""
    samples = np.asarray(samples, dtype=np.float32)
    if samples.ndim == 2:
        samples = samples.mean(axis=1)
    if samples.ndim != 1:
        raise PuppetError(f"expected audio samples shaped (N,) or (N, channels), got {samples.shape}")
    if sample_rate != features.SAMPLE_RATE:
        from math import gcd

        from scipy.signal import resample_poly

        divisor = gcd(int(sample_rate), features.SAMPLE_RATE)
        samples = np.nan_to_num(samples, nan=0.0, posinf=0.0, neginf=0.0)
        samples = resample_poly(samples, features.SAMPLE_RATE // divisor, int(sample_rate) // divisor).astype(np.float32)
    return samples


def stack_steps(log_mel: np.ndarray) -> np.ndarray:
    """(F, 80) log-mel frames → (ceil(F / 2), 160) network steps: frames 2t and 2t + 1 side by side,
    an odd last frame completed with silence."""
    if len(log_mel) % features.FRAMES_PER_MOTION:
        log_mel = np.concatenate([log_mel, np.full((1, features.N_MELS), SILENCE, np.float32)])
    return log_mel.reshape(-1, N_STEP)


def audio_steps(samples: np.ndarray, lookahead: int) -> np.ndarray:
    """(N,) float32 16 kHz mono → (motion_frame_count(N) + lookahead, 160) float32 network input:
    the audio's steps, then `lookahead` steps of silence so that its last motion frames come out."""
    steps = stack_steps(features.log_mel(samples))
    return np.concatenate([steps, np.full((lookahead, N_STEP), SILENCE, np.float32)])


class Predictor:
    """An exported landmark network loaded for inference (one model, many clips and streams)."""

    def __init__(self, model_path: str | Path | None = None, threads: int = 1):
        path = Path(model_path) if model_path is not None else default_model("streaming")
        if not path.exists():
            raise PuppetError(f"no landmark model at {path}: train one with `puppet train` or reinstall puppet")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        self.session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        self.metadata = self.session.get_modelmeta().custom_metadata_map
        spec = json.loads(self.metadata.get("feature_spec", "null"))
        if spec != json.loads(json.dumps(features.SPEC)):
            raise PuppetError(f"{path} was trained on other audio features ({spec}) than puppet computes ({features.SPEC})")
        self.lookahead = int(self.metadata["lookahead_frames"])  # motion frames of audio heard ahead
        self.fps = float(self.metadata["motion_fps"])  # 50
        self.n_landmarks = int(self.metadata["n_landmarks"])  # 68
        self.version = self.metadata.get("version", "")
        self._state_inputs = [i for i in self.session.get_inputs() if i.name not in ("steps", "speaker")]

    def initial_state(self) -> dict[str, np.ndarray]:
        """The network state of a stream that has heard nothing: all zeros."""
        return {i.name: np.zeros(i.shape, np.float32) for i in self._state_inputs}

    def run(self, steps: np.ndarray, speaker: np.ndarray, state: dict[str, np.ndarray]):
        """steps (T, 160) float32, speaker (256,) float32, state → offsets (T, 68, 3) float32 IOD units,
        head frame; rotation (T, 3) float32 radians (pitch, yaw, roll); the state after these steps.
        Output step i is motion frame (steps run before) + i − lookahead."""
        feeds = {"steps": steps[None].astype(np.float32, copy=False), "speaker": speaker[None], **state}
        offsets, rotation, *new_state = self.session.run(None, feeds)
        return offsets[0], rotation[0], {i.name: s for i, s in zip(self._state_inputs, new_state)}

    def predict(self, samples: np.ndarray, speaker: np.ndarray, sample_rate: int = features.SAMPLE_RATE):
        """Motion for a whole clip.

        samples: (N,) or (N, channels) float32 in [-1, 1] at sample_rate (NaN/inf read as silence).
        speaker: (256,) float32 unit-norm embedding from puppet.speaker.embed.
        Returns offsets (T, 68, 3) float32 from the canonical face, inter-ocular distances, head frame,
        and rotation (T, 3) float32 radians (pitch, yaw, roll); T = features.motion_frame_count(N at 16 kHz),
        frame t at t / MOTION_FPS seconds.
        """
        return self.predict_steps(audio_steps(to_mono_16k(samples, sample_rate), 0), speaker)

    def predict_steps(self, steps: np.ndarray, speaker: np.ndarray):
        """`predict` for a clip's (T, 160) network input, as audio_steps(samples, 0) makes it."""
        steps = np.concatenate([steps, np.full((self.lookahead, N_STEP), SILENCE, np.float32)])
        speaker, state = check_speaker(speaker), self.initial_state()
        offsets, rotation = [], []
        for start in range(0, len(steps), OFFLINE_CHUNK):
            o, r, state = self.run(steps[start : start + OFFLINE_CHUNK], speaker, state)
            offsets.append(o)
            rotation.append(r)
        return np.concatenate(offsets)[self.lookahead :], np.concatenate(rotation)[self.lookahead :]

    def stream(self, speaker: np.ndarray) -> "Stream":
        """A new stream for one voice: push 16 kHz audio as it arrives, get motion frames as they become known."""
        return Stream(self, speaker)


class Ensemble:
    """Networks trained apart for the same motion, averaged: where one errs the other often does not, so
    the mean is nearer the truth than either (files use the offline and streaming models together).
    Each runs in a thread of its own (onnxruntime releases the GIL), so on two cores it costs about one."""

    def __init__(self, predictors: tuple[Predictor, ...]):
        self.predictors = predictors

    def predict(self, samples: np.ndarray, speaker: np.ndarray, sample_rate: int = features.SAMPLE_RATE):
        """The mean of the networks' Predictor.predict (same arguments, same shapes); the features are made once."""
        steps = audio_steps(to_mono_16k(samples, sample_rate), 0)
        with ThreadPoolExecutor(len(self.predictors)) as pool:
            answers = list(pool.map(lambda predictor: predictor.predict_steps(steps, speaker), self.predictors))
        offsets = np.mean([offsets for offsets, _ in answers], axis=0, dtype=np.float32)
        rotation = np.mean([rotation for _, rotation in answers], axis=0, dtype=np.float32)
        return offsets, rotation


def check_speaker(speaker: np.ndarray) -> np.ndarray:
    """(256,) float32 speaker embedding, non-finite values zeroed."""
    speaker = np.nan_to_num(np.asarray(speaker, dtype=np.float32).reshape(-1))
    if speaker.shape != (SPEAKER_DIM,):
        raise PuppetError(f"expected a {SPEAKER_DIM}-d speaker embedding, got shape {speaker.shape}")
    return speaker


class Stream:
    """Incremental prediction: `push` audio chunks, each call returns the motion frames completed by it.

    Frames come out in order, each exactly once; after `finish`, their count is
    features.motion_frame_count(all samples pushed) and they equal Predictor.predict of the whole audio.
    """

    def __init__(self, predictor: Predictor, speaker: np.ndarray):
        self.predictor = predictor
        self.speaker = check_speaker(speaker)
        self.state = predictor.initial_state()
        self.samples_seen = 0  # samples pushed so far
        self.next_frame = 0  # the next log-mel frame to compute
        self.tail = np.zeros(CONTEXT_FRAMES * features.HOP, np.float32)  # samples from next_frame·HOP − 320 on
        self.pending = np.zeros((0, features.N_MELS), np.float32)  # a computed log-mel frame waiting for its pair
        self.steps_run = 0
        self.finished = False

    def push(self, samples: np.ndarray):
        """samples: (n,) float32 16 kHz mono (NaN/inf read as silence). Returns offsets (k, 68, 3) and
        rotation (k, 3) for the k ≥ 0 motion frames this chunk completed (see the module docstring)."""
        if self.finished:
            raise PuppetError("this stream is finished: start a new one")
        samples = np.asarray(samples, dtype=np.float32).reshape(-1)
        self.tail = np.concatenate([self.tail, samples])
        self.samples_seen += len(samples)
        ready = max(0, (self.samples_seen - WINDOW_REACH) // features.HOP + 1)  # log-mel frames fully heard
        return self._advance(self._log_mel(ready - self.next_frame))

    def finish(self):
        """End of audio: returns the remaining motion frames (offsets, rotation), silence assumed after the end."""
        if self.finished:
            raise PuppetError("this stream is already finished")
        self.finished = True
        frames = self._log_mel(features.frame_count(self.samples_seen) - self.next_frame)
        if (len(self.pending) + len(frames)) % features.FRAMES_PER_MOTION:
            frames = np.concatenate([frames, np.full((1, features.N_MELS), SILENCE, np.float32)])
        silence = np.full((self.predictor.lookahead * features.FRAMES_PER_MOTION, features.N_MELS), SILENCE, np.float32)
        return self._advance(np.concatenate([frames, silence]))

    def _log_mel(self, count: int) -> np.ndarray:
        """(count, 80) log-mel frames next_frame … next_frame + count − 1, computed by features.log_mel on
        the kept samples, whose first CONTEXT_FRAMES frames only serve as the earlier frames' context."""
        if count <= 0:
            return np.zeros((0, features.N_MELS), np.float32)
        frames = features.log_mel(self.tail)[CONTEXT_FRAMES : CONTEXT_FRAMES + count]
        self.next_frame += count
        self.tail = self.tail[count * features.HOP :]
        return frames

    def _advance(self, frames: np.ndarray):
        """Run the network over the complete steps among pending + frames; drop its first lookahead outputs."""
        frames = np.concatenate([self.pending, frames])
        usable = len(frames) - len(frames) % features.FRAMES_PER_MOTION
        self.pending = frames[usable:]
        if usable == 0:
            return np.zeros((0, self.predictor.n_landmarks, 3), np.float32), np.zeros((0, 3), np.float32)
        offsets, rotation, self.state = self.predictor.run(frames[:usable].reshape(-1, N_STEP), self.speaker, self.state)
        skip = max(0, self.predictor.lookahead - self.steps_run)
        self.steps_run += len(offsets)
        return offsets[skip:], rotation[skip:]
