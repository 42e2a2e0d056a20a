"""Train the audio → landmark network (puppet.network) on a corpus folder and export it to ONNX.

    python -m puppet.train --corpus corpus/ --out runs/landmarks [--steps N]

Reads top to bottom: config, data, model (from scratch or resumed from out/checkpoint.pt),
optimizers, evaluation, the loop, export. The corpus folder (built by puppet.corpus and the labellers):
    manifest.jsonl      one {"id", "text", "speaker", "heldout": bool, "seconds", ...} per line
    audio/ID.wav        16 kHz mono int16
    targets/ID.npz      offsets (T, 68, 3) float32 IOD units from the canonical face, head frame;
                        rotation (T, 3) float32 radians (pitch, yaw, roll); fps = 50;
                        T = features.motion_frame_count(samples)
    phones/ID.json      the aligned phones the targets were made from (puppet.labels): the phone
                        classifier's labels
    embeddings/ID.npy   (256,) float32 speaker embedding, computed here with puppet.speaker.embed and
                        cached when missing
Only ids with targets and phones are used (labelling may still be running); held-out speakers are never
trained on, only evaluated. Every eval_every steps the last eval_utterances held-out utterances are scored;
the checkpoint with their lowest position loss is kept as out/best.pt and is the one exported (later steps
can fit the training voices better and unseen voices worse).

Then a small voice detector (network.VoiceNet, out/voice.pt) learns the corpus's speech against made-up
music, tones, noise and knocks (puppet.nonspeech), alone and under the speech, and is exported with the
network: the offsets are scaled down where it is sure nobody speaks (network.GatedNetwork).
"""
import argparse
import io
import json
import math
import os
import sys
import time
import warnings
import wave
from dataclasses import asdict, dataclass, field, replace
from itertools import pairwise
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from puppet import features, nonspeech
from puppet.alignment import PHONES
from puppet.alignment import SILENCE as SILENT_PHONE
from puppet.errors import PuppetError
from puppet.motion import interpolate_rows
from puppet.network import (
    LOOKAHEAD,
    N_LANDMARKS,
    Discriminator,
    GatedNetwork,
    Network,
    NetworkConfig,
    VoiceNet,
    laplacian_loss,
    lsgan_generator_loss,
    lsgan_losses,
    mouth_area_loss,
    parameter_count,
    phone_loss,
    position_loss,
    soft_limit,
    velocity_loss,
)
from puppet.predictor import N_STEP, SILENCE, audio_steps
from puppet.visemes import canonical_rest

MODEL_VERSION = "2"  # bump when the exported inputs, outputs or their meaning change
CHECKPOINT = "checkpoint.pt"
BEST_CHECKPOINT = "best.pt"  # the checkpoint with the lowest held-out position loss so far: the one exported
LOG = "log.jsonl"
ONNX_FILE = "landmarks.onnx"
EXPORT_TOLERANCE = 1e-4  # onnxruntime vs torch, absolute, on every output
PHONE_CLASSES = (SILENT_PHONE, *PHONES)  # the phone classifier's classes, in order
SILENT_CLASS = PHONE_CLASSES.index(SILENT_PHONE)


@dataclass(frozen=True)
class TrainConfig:
    corpus: str = "corpus"  # corpus folder (see the module docstring)
    out: str = "runs/landmarks"  # checkpoint.pt, log.jsonl and landmarks.onnx go here
    seed: int = 1337
    batch_size: int = 16  # training windows per step
    sequence_frames: int = 128  # motion frames per training window (2.56 s at 50 fps)
    lr: float = 1e-3  # peak learning rate (Adam)
    min_lr: float = 1e-5  # the cosine schedule's floor
    warmup_steps: int = 200  # linear warm-up before the cosine decay
    steps: int = 10000  # total optimizer steps (a resumed run continues up to this); on the 6 h corpus held-out loss still falls at 9k
    eval_every: int = 1000  # steps between evaluations on the held-out speakers
    checkpoint_every: int = 250  # steps between checkpoints
    log_every: int = 10  # steps between training-loss lines in log.jsonl
    laplacian_weight: float = 1.0  # λ of Eq. 8 and 12 (paper: 1)
    rotation_weight: float = 10.0  # head rotation (radians²) against landmark positions (IOD², summed over 68)
    content_weight: float = 0.5  # the content branch alone must fit the targets too: it carries the mouth
    velocity_weight: float = 5.0  # frame-to-frame velocity error (IOD² per frame pair, summed over 68) against positions
    mouth_weight: float = 0.5  # absolute error of the inner mouth's area (IOD²) against positions; 0: none (see mouth_area_loss)
    gan: bool = True  # train the speaker branch against the LSGAN discriminator of Eq. 10–12
    gan_weight: float = 0.01  # μ_s of Eq. 12
    grad_clip: float = 1.0
    threads: int = 0  # torch intra-op threads; 0 leaves torch's default
    device: str = "cpu"  # "cuda" to train on a GPU
    eval_utterances: int = 64  # held-out utterances that choose the exported checkpoint (the last ones; puppet eval scores the first)
    export: bool = True  # write out/landmarks.onnx at the end, checked against torch
    feature_augment: bool = True  # recolour, re-level and band-mask each training window's log-mels (see augment_steps)
    silence_tails: float = 0.1  # share of training windows cut to silence part-way, the mouth easing to rest (see silence_tail)
    tempo_changes: float = 0.0  # share of training windows sped up or slowed down, sound and motion alike (see stretched_window)
    phone_weight: float = 0.0  # the phone classifier's cross-entropy (nats per frame) against positions; 0: none (see phone_loss)
    voice_steps: int = 3000  # steps training the voice detector exported with the network (see train_voice); 0: none
    voice_sounds: int = 300  # made-up non-speech clips it trains on (puppet.nonspeech), SOUND_SECONDS each
    network: NetworkConfig = field(default_factory=lambda: NetworkConfig(dropout=0.1))  # ignored when resuming


# The two shipped models (puppet.predictor.MODEL_FILES): TrainConfig's defaults with these changes
# (lookahead in motion frames). The live window can wait only 60 ms for the future; a file is known whole, so its model hears the
# 300 ms the paper's content window spans. Tempo changes and the phone classifier helped the live model
# (real video, held-out voices) and not the offline one (assets/models/README.md), so only the live
# model trains with them.
RECIPES = {
    "streaming": {"lookahead": LOOKAHEAD, "tempo_changes": 0.5, "phone_weight": 0.02},
    "offline": {"lookahead": 15, "tempo_changes": 0.0, "phone_weight": 0.0},
}


def classifier_size(phone_weight: float) -> int:
    """NetworkConfig.phone_classes for a phone-loss weight: a classifier head only where it is trained."""
    return len(PHONE_CLASSES) if phone_weight > 0 else 0


def recipe(kind: str, corpus: str, out: str) -> TrainConfig:
    """The TrainConfig that made the shipped `kind` model ("streaming" or "offline")."""
    base, settings = TrainConfig(), RECIPES[kind]
    return replace(base, corpus=corpus, out=out, tempo_changes=settings["tempo_changes"], phone_weight=settings["phone_weight"],
                   network=replace(base.network, lookahead=settings["lookahead"], phone_classes=classifier_size(settings["phone_weight"])))


# -- data ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Utterance:
    """One labelled utterance, ready for training (T motion frames, L = lookahead).
    steps (T + L, 160) float32 log-mels, silence after the end; offsets (T, 68, 3); rotation (T, 3);
    speaker (256,) float32 unit-norm embedding; phones (T,) int64 index into PHONE_CLASSES of each frame."""

    id: str
    speaker_id: str
    steps: np.ndarray
    offsets: np.ndarray
    rotation: np.ndarray
    speaker: np.ndarray
    phones: np.ndarray


def read_wav(path: Path) -> np.ndarray:
    """(N,) float32 in [-1, 1] from a 16 kHz mono int16 WAV file."""
    with wave.open(str(path), "rb") as f:
        if (f.getframerate(), f.getnchannels(), f.getsampwidth()) != (features.SAMPLE_RATE, 1, 2):
            raise PuppetError(f"{path}: expected 16 kHz mono 16-bit audio")
        data = f.readframes(f.getnframes())
    return np.frombuffer(data, dtype="<i2").astype(np.float32) / 32768.0


def speaker_embedding(corpus: Path, utterance_id: str, samples: np.ndarray) -> np.ndarray:
    """(256,) float32 embedding of one utterance's voice, cached as embeddings/ID.npy."""
    path = corpus / "embeddings" / f"{utterance_id}.npy"
    if path.exists():
        return np.load(path).astype(np.float32)
    from puppet.speaker import (
        embed,  # written alongside; imported only when an embedding is missing
    )

    embedding = np.asarray(embed(samples), dtype=np.float32)
    path.parent.mkdir(exist_ok=True)
    np.save(path, embedding)
    return embedding


def frame_phones(rows: list[dict], frames: int) -> np.ndarray:
    """(frames,) int64 index into PHONE_CLASSES of the phone spoken at each motion frame's centre, from
    phones/ID.json rows ({"phone", "start", "end"} in seconds, tiling the audio); silence past the last."""
    centres = (np.arange(frames) + 0.5) / features.MOTION_FPS
    ends = np.array([row["end"] for row in rows])
    classes = np.array([PHONE_CLASSES.index(row["phone"]) for row in rows] + [SILENT_CLASS], np.int64)
    return classes[np.searchsorted(ends, centres, side="right")]


def load_corpus(corpus: Path, lookahead: int) -> tuple[list[Utterance], list[Utterance]]:
    """(training utterances, held-out utterances) among the manifest's ids that have targets."""
    manifest = corpus / "manifest.jsonl"
    if not manifest.exists():
        raise PuppetError(f"no corpus at {corpus}: {manifest} is missing")
    train, heldout = [], []
    for line in manifest.read_text().splitlines():
        if not line.strip():
            continue
        entry = json.loads(line)
        target_path = corpus / "targets" / f"{entry['id']}.npz"
        phones_path = corpus / "phones" / f"{entry['id']}.json"
        if not (target_path.exists() and phones_path.exists()):
            continue  # not labelled yet
        samples = read_wav(corpus / "audio" / f"{entry['id']}.wav")
        target = np.load(target_path)
        frames = features.motion_frame_count(len(samples))
        if target["offsets"].shape != (frames, N_LANDMARKS, 3) or target["rotation"].shape != (frames, 3):
            raise PuppetError(f"{target_path}: expected {frames} frames of offsets (T, 68, 3) and rotation (T, 3)")
        phones = json.loads(phones_path.read_text())
        utterance = Utterance(
            entry["id"], str(entry["speaker"]), audio_steps(samples, lookahead),
            target["offsets"].astype(np.float32), target["rotation"].astype(np.float32),
            speaker_embedding(corpus, entry["id"], samples), frame_phones(phones, frames),
        )
        (heldout if entry.get("heldout") else train).append(utterance)
    if not train:
        raise PuppetError(f"{corpus} has no labelled training utterances yet (targets/ID.npz)")
    return train, heldout


def sample_batch(utterances: list[Utterance], config: TrainConfig, lookahead: int, rng: np.random.Generator) -> dict:
    """A batch of random windows, utterances drawn in proportion to their length:
    steps (B, S + L, 160), speaker (B, 256), offsets (B, S, 68, 3), rotation (B, S, 3), phones (B, S), mask (B, S),
    where network output step L + i is target frame i (S = sequence_frames, L = lookahead)."""
    frames = config.sequence_frames
    lengths = np.array([len(u.offsets) for u in utterances], np.float64)
    batch = {
        "steps": np.full((config.batch_size, frames + lookahead, N_STEP), SILENCE, np.float32),
        "speaker": np.zeros((config.batch_size, 256), np.float32),
        "offsets": np.zeros((config.batch_size, frames, N_LANDMARKS, 3), np.float32),
        "rotation": np.zeros((config.batch_size, frames, 3), np.float32),
        "phones": np.full((config.batch_size, frames), SILENT_CLASS, np.int64),
        "mask": np.zeros((config.batch_size, frames), np.float32),
    }
    for b, index in enumerate(rng.choice(len(utterances), config.batch_size, p=lengths / lengths.sum())):
        u = utterances[index]
        rate = rng.uniform(*TEMPO_RANGE) if rng.random() < config.tempo_changes else 1.0
        span = int(np.ceil(frames * rate))  # source frames the window covers
        start = int(rng.integers(0, max(1, len(u.offsets) - span + 1)))
        n = min(frames, int((len(u.offsets) - start) / rate))
        window, offsets, rotation, phones = stretched_window(u, start, n, lookahead, rate)
        batch["steps"][b, : n + lookahead] = augment_steps(window, rng) if config.feature_augment else window
        batch["speaker"][b] = u.speaker
        batch["offsets"][b, :n] = offsets
        batch["rotation"][b, :n] = rotation
        batch["phones"][b, :n] = phones
        batch["mask"][b, :n] = 1.0
        if n > REST_FRAMES and rng.random() < config.silence_tails:
            cut = int(rng.integers(n // 4, n))
            silence_tail(batch["steps"][b], batch["offsets"][b], batch["rotation"][b], n, cut)
            batch["phones"][b, cut:] = SILENT_CLASS
    return {k: torch.from_numpy(v).to(config.device) for k, v in batch.items()}


TEMPO_RANGE = (0.8, 1.5)  # speaking-rate factors of stretched windows (the corpus's own TTS tempo spans 0.85–1.2)


def stretched_window(u: Utterance, start: int, frames: int, lookahead: int, rate: float):
    """A window of `frames` motion frames from motion frame `start` of u, played `rate` times as fast
    (rate 1: the window as it is): (steps (frames + L, 160), offsets (frames, 68, 3), rotation (frames, 3),
    phones (frames,)). Log-mel frames (100 per second) and motion frames (50) are resampled linearly on one
    time axis (phones: the nearest frame's), so a sound and the mouth that makes it stay together; pitch is
    kept, as in a tempo change."""
    if rate == 1.0:
        end = start + frames
        return u.steps[start : end + lookahead], u.offsets[start:end], u.rotation[start:end], u.phones[start:end]
    mel = u.steps.reshape(-1, features.N_MELS)  # (2(T + L), 80), frame k centred at (k + 0.5) / 100 s
    k = np.arange(2 * (frames + lookahead))
    steps = interpolate_rows(mel, 2 * start + (k + 0.5) * rate - 0.5).reshape(-1, N_STEP)
    j = start + (np.arange(frames) + 0.5) * rate - 0.5  # motion frame j centred at (j + 0.5) / 50 s
    phones = u.phones[np.clip(np.rint(j).astype(int), 0, len(u.phones) - 1)]
    return steps, interpolate_rows(u.offsets, j), interpolate_rows(u.rotation, j), phones


# Feature-domain augmentation, drawn afresh for every training window (log10 mel units; 1 = 10 dB of power).
EQ_STD = 0.15  # each of EQ_TERMS cosine terms across the mel axis: a smooth microphone colouring of about ±5 dB
EQ_TERMS = 3
LEVEL_RANGE = 0.6  # uniform level change in ±this (±6 dB)
MAX_BAND_MASKS = 2  # frequency bands replaced by the window's mean (SpecAugment's frequency masking)
MAX_BAND_WIDTH = 8  # mel bins


def augment_steps(steps: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(S, 160) float32 network steps (two 80-bin log-mel frames each) with one random colouring, level
    change and up to MAX_BAND_MASKS masked bands applied to every frame; digital silence stays silence."""
    mel = steps.reshape(len(steps), 2, features.N_MELS).copy()
    silent = mel <= SILENCE + 1e-6
    axis = np.linspace(0.0, 1.0, features.N_MELS)
    colour = sum(rng.normal(0.0, EQ_STD) * np.cos(np.pi * (k + 1) * axis) for k in range(EQ_TERMS))
    mel = np.maximum(mel + colour + rng.uniform(-LEVEL_RANGE, LEVEL_RANGE), SILENCE)
    for _ in range(int(rng.integers(0, MAX_BAND_MASKS + 1))):
        width = int(rng.integers(1, MAX_BAND_WIDTH + 1))
        low = int(rng.integers(0, features.N_MELS - width))
        mel[..., low : low + width] = mel[~silent].mean() if (~silent).any() else SILENCE
    mel[silent] = SILENCE
    return mel.reshape(steps.shape).astype(np.float32)


REST_FRAMES = 5  # after a silence tail's cut the mouth eases to rest over this many frames (100 ms)


def silence_tail(steps: np.ndarray, offsets: np.ndarray, rotation: np.ndarray, frames: int, cut: int) -> None:
    """Cut one training window to digital silence from motion frame `cut` on, in place: steps (S + L, 160)
    become SILENCE from step `cut`; offsets (S, 68, 3) ease from their value at the cut to rest over
    REST_FRAMES; rotation (S, 3) holds its value at the cut. Teaches the network that the mouth comes to
    rest when the voice stops, however long the silence (a live noise gate hands it digital silence)."""
    steps[cut:] = SILENCE
    ease = np.clip(1.0 - np.arange(1, frames - cut + 1) / REST_FRAMES, 0.0, 1.0)
    offsets[cut:frames] = offsets[cut - 1] * ease[:, None, None]
    rotation[cut:frames] = rotation[cut - 1]


def feature_stats(utterances: list[Utterance], lookahead: int) -> tuple[np.ndarray, np.ndarray]:
    """(160,) mean and std of the training log-mels (the silence padding left out)."""
    steps = np.concatenate([u.steps[: len(u.steps) - lookahead] for u in utterances])
    return steps.mean(0), steps.std(0)


# -- losses ----------------------------------------------------------------------------------------


def generator_losses(model: Network, batch: dict, config: TrainConfig, discriminator: Discriminator | None = None):
    """(total loss, the network's output trimmed to the target frames, a dict of float terms for the log)."""
    lookahead, mask = model.config.lookahead, batch["mask"]
    out = model.run(batch["steps"], batch["speaker"], model.initial_state(len(mask)))
    offsets, rotation = out.offsets[:, lookahead:], out.rotation[:, lookahead:]
    content = out.content[:, lookahead:].unflatten(-1, (N_LANDMARKS, 3))
    terms = {
        "position": position_loss(offsets, batch["offsets"], mask),
        "laplacian": laplacian_loss(offsets, batch["offsets"], mask),
        "rotation": ((rotation - batch["rotation"]).square().sum(-1) * mask).sum() / mask.sum().clamp(min=1.0),
        "content_position": position_loss(content, batch["offsets"], mask),
        "content_laplacian": laplacian_loss(content, batch["offsets"], mask),
        "velocity": velocity_loss(offsets, batch["offsets"], mask),
    }
    total = (
        terms["position"] + config.laplacian_weight * terms["laplacian"] + config.rotation_weight * terms["rotation"]
        + config.content_weight * (terms["content_position"] + config.laplacian_weight * terms["content_laplacian"])
        + config.velocity_weight * terms["velocity"]
    )
    if config.mouth_weight > 0:
        rest = torch.from_numpy(canonical_rest()).to(offsets.device)
        terms["mouth"] = mouth_area_loss(offsets, batch["offsets"], rest, mask)
        terms["content_mouth"] = mouth_area_loss(content, batch["offsets"], rest, mask)
        total = total + config.mouth_weight * (terms["mouth"] + config.content_weight * terms["content_mouth"])
    if out.phones is not None and config.phone_weight > 0:
        logits = out.phones[:, lookahead:]
        terms["phone"] = phone_loss(logits, batch["phones"], mask)
        terms["phone_accuracy"] = ((logits.argmax(-1) == batch["phones"]).float() * mask).sum() / mask.sum().clamp(min=1.0)
        total = total + config.phone_weight * terms["phone"]
    fake = None
    if discriminator is not None:
        # The adversarial gradient reaches only the speaker branch (rotation and expression), as in §4.2.
        fake = speaker_branch_offsets(model, out, lookahead)
        terms["adversarial"] = lsgan_generator_loss(discriminator(fake, rotation, *discriminator_context(out, lookahead)), mask)
        total = total + config.gan_weight * terms["adversarial"]
    terms["total"] = total
    return total, (out, fake), {k: float(v.detach()) for k, v in terms.items()}


def speaker_branch_offsets(model: Network, out, lookahead: int) -> torch.Tensor:
    """(B, S, 68, 3) output offsets with the content branch's share held fixed."""
    offsets = soft_limit(out.content.detach() + out.expression, model.config.offset_limit)[:, lookahead:]
    return offsets.unflatten(-1, (N_LANDMARKS, 3))


def discriminator_context(out, lookahead: int) -> tuple[torch.Tensor, torch.Tensor]:
    """What the discriminator judges the motion against: c̃ (B, S, C) and the reduced speaker (B, 128)."""
    return out.code[:, lookahead:].detach(), out.speaker.detach()


def validation_set(heldout: list[Utterance], config: TrainConfig) -> list[Utterance]:
    """The held-out utterances whose loss chooses the checkpoint to export: the last
    config.eval_utterances of them, apart from the first ones that `puppet eval --corpus` scores."""
    return heldout[-config.eval_utterances :]


@torch.no_grad()
def evaluate(model: Network, utterances: list[Utterance], config: TrainConfig) -> dict:
    """Mean losses over whole held-out utterances, each run from the start as at inference."""
    model.eval()
    sums: dict[str, float] = {}
    for u in utterances:
        frames = len(u.offsets)
        batch = {
            "steps": u.steps[None], "speaker": u.speaker[None], "offsets": u.offsets[None],
            "rotation": u.rotation[None], "phones": u.phones[None], "mask": np.ones((1, frames), np.float32),
        }
        batch = {k: torch.from_numpy(v).to(config.device) for k, v in batch.items()}
        _, _, terms = generator_losses(model, batch, config)
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + v
    model.train()
    return {k: v / len(utterances) for k, v in sums.items()}


# -- checkpoints and export ------------------------------------------------------------------------


def network_config(args: dict) -> NetworkConfig:
    """The NetworkConfig stored in a checkpoint as a dict."""
    return NetworkConfig(**{**args, "content_mlp": tuple(args["content_mlp"])})


def load_network(checkpoint: Path) -> tuple[Network, dict]:
    """The network of a checkpoint (in eval mode) and the checkpoint itself; nothing else needed."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=True)
    model = Network(network_config(state["model_args"]))
    model.load_state_dict(state["model"])
    return model.eval(), state


def _protobuf_field(number: int, payload: bytes) -> bytes:
    """A length-delimited protobuf field: tag, length, payload (varints)."""

    def varint(n: int) -> bytes:
        out = bytearray()
        while True:
            out.append((n & 0x7F) | (0x80 if n > 0x7F else 0))
            n >>= 7
            if not n:
                return bytes(out)

    return varint(number << 3 | 2) + varint(len(payload)) + payload


def with_metadata(model: bytes, metadata: dict[str, str]) -> bytes:
    """An ONNX ModelProto with metadata_props (field 14) entries appended: repeated protobuf fields may
    follow the rest of a message, so this needs no `onnx` package."""
    entries = (_protobuf_field(1, k.encode()) + _protobuf_field(2, v.encode()) for k, v in metadata.items())
    return model + b"".join(_protobuf_field(14, entry) for entry in entries)


def export(checkpoint: str | Path, path: str | Path, voice: str | Path | None = None) -> Path:
    """Write the checkpoint's network as ONNX (time axis dynamic, batch 1) with its metadata, then check
    onnxruntime's outputs against torch's (EXPORT_TOLERANCE). Inputs: steps (1, T, 160), speaker (1, 256),
    h, c, past, valid (the State); outputs: offsets (1, T, 68, 3), rotation (1, T, 3), h_out, c_out,
    past_out, valid_out. With a voice detector checkpoint (train_voice), the offsets are gated by it
    (network.GatedNetwork) and its GRU state is one more input and output: voice_h (1, 1, 64), voice_h_out."""
    import onnxruntime as ort

    network, state = load_network(Path(checkpoint))
    detector, voice_state = load_voice(Path(voice)) if voice is not None else (None, None)
    model = GatedNetwork(network, detector).eval() if detector is not None else network
    generator = torch.Generator().manual_seed(0)
    speaker = torch.nn.functional.normalize(torch.randn(1, 256, generator=generator), dim=-1)
    warm = torch.randn(1, 23, N_STEP, generator=generator) * 1.5 - 2.5
    steps = torch.randn(1, 37, N_STEP, generator=generator) * 1.5 - 2.5
    with torch.no_grad():
        start = network.run(warm, speaker, network.initial_state()).state  # a lived-in state, not only zeros
        if detector is not None:
            start = (*start, detector(warm, detector.initial_state())[1])
        expected = model(steps, speaker, *start)
    names = ["h", "c", "past", "valid"] + (["voice_h"] if detector is not None else [])
    buffer = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model, (steps, speaker, *start), buffer, dynamo=False, opset_version=17,
            input_names=["steps", "speaker", *names], output_names=["offsets", "rotation", *(n + "_out" for n in names)],
            dynamic_axes={"steps": {1: "time"}, "offsets": {1: "time"}, "rotation": {1: "time"}},
        )
    metadata = {
        "feature_spec": json.dumps(features.SPEC),
        "motion_fps": str(features.MOTION_FPS),
        "n_landmarks": str(N_LANDMARKS),
        "lookahead_frames": str(network.config.lookahead),
        "window_frames": str(network.config.window),
        "version": MODEL_VERSION,
        "network": json.dumps(state["model_args"]),
        "training": json.dumps(state.get("training", {})),
        "outputs": "offsets (1,T,68,3) float32 inter-ocular distances from the canonical face, head frame; "
        "rotation (1,T,3) float32 radians (pitch, yaw, roll); output step i is motion frame i - lookahead_frames",
    }
    if voice_state is not None:
        metadata["voice_detector"] = json.dumps({"steps": voice_state["step"], "held_out": voice_state["validation"]})
    onnx_bytes = with_metadata(buffer.getvalue(), metadata)
    session = ort.InferenceSession(onnx_bytes, providers=["CPUExecutionProvider"])
    feeds = {"steps": steps.numpy(), "speaker": speaker.numpy(), **{n: s.numpy() for n, s in zip(names, start)}}
    for name, got, want in zip(["offsets", "rotation", *names], session.run(None, feeds), expected):
        error = float(np.abs(got - want.numpy()).max())
        if error > EXPORT_TOLERANCE:
            raise RuntimeError(f"ONNX export differs from torch on {name}: max |error| {error:.2e} > {EXPORT_TOLERANCE}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(onnx_bytes)
    return path


def held_out_position(checkpoint: Path) -> float:
    """The held-out position loss a checkpoint was saved with; infinity when there is none."""
    if not checkpoint.exists():
        return math.inf
    validation = torch.load(checkpoint, map_location="cpu", weights_only=True)["training"]["validation"]
    return validation["position"] if validation else math.inf


def save_checkpoint(path: Path, state: dict) -> None:
    """Write atomically, so a run killed mid-save keeps its previous checkpoint."""
    temporary = path.with_suffix(".tmp")
    torch.save(state, temporary)
    os.replace(temporary, path)


def learning_rate(step: int, config: TrainConfig) -> float:
    """Linear warm-up to lr, then cosine decay to min_lr at the last step."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    progress = min(1.0, (step - config.warmup_steps) / max(1, config.steps - config.warmup_steps))
    return config.min_lr + 0.5 * (config.lr - config.min_lr) * (1 + math.cos(math.pi * progress))


# -- the voice detector (network.VoiceNet) ---------------------------------------------------------

VOICE_FILE = "voice.pt"  # the voice detector's checkpoint, beside the network's
VOICE_HIDDEN = 64
VOICE_WINDOW = 200  # motion frames per training window (4 s)
VOICE_BATCH = 32
VOICE_LR = 2e-3  # peak learning rate, cosine decay to a tenth
VOICE_CHECKPOINT_EVERY = 500
VOICE_PAUSE_FRAMES = 15  # a silence between words this long (0.3 s) or longer is not speech: the face rests there
SOUND_SECONDS = 6.0  # each made-up non-speech clip (TrainConfig.voice_sounds of them; a tenth as many more held out)
SOUND_ONLY = 0.35  # share of windows that are a sound alone
SOUND_UNDER = 0.4  # share of the other windows with a sound under the speech
SNR_DB = (-5.0, 25.0)  # speech power over sound power, for a sound under speech and for a lone sound (against a random utterance)


def voice_labels(phones: np.ndarray) -> np.ndarray:
    """(T,) float32: 1 where a frame is speech (a phone, or a silence shorter than VOICE_PAUSE_FRAMES between
    two phones), else 0; phones (T,) int64 PHONE_CLASSES indices as Utterance.phones."""
    speaking = np.flatnonzero(phones != SILENT_CLASS)
    labels = np.zeros(len(phones), np.float32)
    labels[speaking] = 1.0
    for last, following in pairwise(speaking):
        if 1 < following - last <= VOICE_PAUSE_FRAMES:
            labels[last + 1 : following] = 1.0
    return labels


def sound_bank(count: int, rng: np.random.Generator) -> list[np.ndarray]:
    """`count` non-speech clips as network steps, each (motion_frame_count(SOUND_SECONDS · 16 kHz), 160) float32."""
    return [audio_steps(nonspeech.sound(SOUND_SECONDS, rng), 0) for _ in range(count)]


def mel_power(steps: np.ndarray) -> np.ndarray:
    """Mel power of log10-mel steps, the LOG_FLOOR that features.log_mel adds to silence taken back off."""
    return np.maximum(10.0**steps - features.LOG_FLOOR, 0.0)


def mix(speech: np.ndarray, sound: np.ndarray, snr_db: float, reference: float | None = None) -> np.ndarray:
    """Steps of speech with a sound under it, both (S, 160) log10 mels, added as mel powers (their cross
    terms average out over a mel band). The sound is scaled to `snr_db` below the speech's mean power
    (or below `reference`, a mean power, when given)."""
    speech_power, sound_power = mel_power(speech), mel_power(sound)
    target = speech_power.mean() if reference is None else reference
    gain = target / max(float(sound_power.mean()), 1e-12) * 10.0 ** (-snr_db / 10.0)
    return np.log10(speech_power + gain * sound_power + features.LOG_FLOOR).astype(np.float32)


def voice_batch(utterances: list[Utterance], sounds: list[np.ndarray], lookahead: int, rng: np.random.Generator) -> dict:
    """steps (B, S + L, 160) and labels (B, S) (1: speech) of random windows, B = VOICE_BATCH, S = VOICE_WINDOW:
    speech (with or without a sound under it) or a sound alone; output step L + i is label i."""
    span = VOICE_WINDOW + lookahead
    steps = np.full((VOICE_BATCH, span, N_STEP), SILENCE, np.float32)
    labels = np.zeros((VOICE_BATCH, VOICE_WINDOW), np.float32)
    lengths = np.array([len(u.phones) for u in utterances], np.float64)
    chances = lengths / lengths.sum()  # utterances drawn in proportion to their length
    for b in range(VOICE_BATCH):
        u = utterances[rng.choice(len(utterances), p=chances)]
        sound = sounds[int(rng.integers(len(sounds)))]
        start = int(rng.integers(0, len(sound) - span + 1))
        sound = sound[start : start + span]
        if rng.random() < SOUND_ONLY:  # as loud as the drawn utterance, give or take SNR_DB
            steps[b] = mix(np.full_like(sound, SILENCE), sound, rng.uniform(*SNR_DB), reference=float(mel_power(u.steps).mean()))
        else:
            start = int(rng.integers(0, max(1, len(u.phones) - VOICE_WINDOW + 1)))
            window = u.steps[start : start + span]
            steps[b, : len(window)] = window
            said = voice_labels(u.phones)[start : start + VOICE_WINDOW]
            labels[b, : len(said)] = said
            if rng.random() < SOUND_UNDER:
                steps[b] = mix(steps[b], sound, rng.uniform(*SNR_DB))
        steps[b] = augment_steps(steps[b], rng)
    return {"steps": torch.from_numpy(steps), "labels": torch.from_numpy(labels)}


def voice_scores(model: VoiceNet, utterances: list[Utterance], sounds: list[np.ndarray]) -> dict:
    """How the detector does on whole held-out utterances and sounds: the mean probability of speech on
    speech frames, on the utterances' pauses, and on sounds alone, and the share of frames it gets right."""
    probabilities = {"speech": [], "pauses": [], "sounds": []}
    with torch.no_grad():
        for u in utterances:
            logits, _ = model(torch.from_numpy(u.steps)[None], model.initial_state())
            p, labels = torch.sigmoid(logits[0, model.lookahead :]).numpy(), voice_labels(u.phones)
            probabilities["speech"].append(p[labels > 0.5])
            probabilities["pauses"].append(p[labels < 0.5])
        for sound in sounds:
            logits, _ = model(torch.from_numpy(sound)[None], model.initial_state())
            probabilities["sounds"].append(torch.sigmoid(logits[0]).numpy())
    joined = {k: np.concatenate(v) if v else np.zeros(0) for k, v in probabilities.items()}
    right = np.concatenate([joined["speech"] > 0.5, joined["pauses"] < 0.5, joined["sounds"] < 0.5])
    return {**{f"p_{k}": float(v.mean()) if len(v) else float("nan") for k, v in joined.items()}, "accuracy": float(right.mean())}


def train_voice(utterances: list[Utterance], heldout: list[Utterance], config: TrainConfig, lookahead: int) -> Path:
    """Train (or resume) the voice detector for a network that hears `lookahead` steps ahead, on the
    corpus's speech against made-up sounds (puppet.nonspeech); saved as out/VOICE_FILE and returned."""
    path = Path(config.out) / VOICE_FILE
    resumed = torch.load(path, map_location="cpu", weights_only=True) if path.exists() else None
    if resumed and resumed["step"] >= config.voice_steps and resumed["validation"] is not None:
        return path  # trained and scored already: making its sounds again would change nothing
    rng = np.random.default_rng(config.seed + 1)
    sounds = sound_bank(config.voice_sounds, rng)
    heldout_sounds = sound_bank(max(1, config.voice_sounds // 10), np.random.default_rng(config.seed + 2))
    model = VoiceNet(VOICE_HIDDEN, lookahead)
    optimizer = torch.optim.Adam(model.parameters(), lr=VOICE_LR)
    step = 0
    if resumed:
        model.load_state_dict(resumed["model"])
        optimizer.load_state_dict(resumed["optimizer"])
        step = resumed["step"]
        rng.bit_generator.state = json.loads(resumed["rng"])
    else:
        mean, std = feature_stats(utterances, lookahead)
        model.feature_mean.copy_(torch.as_tensor(mean))
        model.feature_std.copy_(torch.as_tensor(np.maximum(std, 1e-3)))

    def save(validation: dict | None) -> None:
        save_checkpoint(path, {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "step": step,
                               "hidden": VOICE_HIDDEN, "lookahead": lookahead, "rng": json.dumps(rng.bit_generator.state),
                               "validation": validation})

    model.train()
    with open(Path(config.out) / LOG, "a") as log, \
            tqdm(total=config.voice_steps, initial=step, desc="voice detector", unit="step", mininterval=1.0) as progress:
        while step < config.voice_steps:
            progress_share = step / max(1, config.voice_steps)
            for group in optimizer.param_groups:
                group["lr"] = VOICE_LR * (0.55 + 0.45 * math.cos(math.pi * progress_share))
            batch = voice_batch(utterances, sounds, lookahead, rng)
            logits, _ = model(batch["steps"], model.initial_state(VOICE_BATCH))
            loss = torch.nn.functional.binary_cross_entropy_with_logits(logits[:, lookahead:], batch["labels"])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            step += 1
            progress.update()
            progress.set_postfix(loss=f"{loss.item():.4f}", refresh=False)
            if step % config.log_every == 0:
                log.write(json.dumps({"voice_step": step, "loss": loss.item()}) + "\n")
            if step % VOICE_CHECKPOINT_EVERY == 0 and step < config.voice_steps:
                save(None)
    model.eval()
    validation = voice_scores(model, heldout[: config.eval_utterances], heldout_sounds)
    print("voice detector on held-out voices and sounds: " + ", ".join(f"{k} {v:.3f}" for k, v in validation.items()))
    save(validation)
    return path


def load_voice(path: Path) -> tuple[VoiceNet, dict]:
    """The voice detector of a checkpoint (eval mode) and the checkpoint itself."""
    state = torch.load(path, map_location="cpu", weights_only=True)
    model = VoiceNet(state["hidden"], state["lookahead"])
    model.load_state_dict(state["model"])
    return model.eval(), state


# -- the run ---------------------------------------------------------------------------------------


def train(config: TrainConfig) -> Path:
    """Train (or resume) to config.steps; returns the path of the checkpoint exported (the ONNX model
    lies beside it): the one with the lowest held-out position loss, the last one without held-out speakers."""
    out = Path(config.out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint_path, best_path = out / CHECKPOINT, out / BEST_CHECKPOINT
    if config.threads > 0:
        torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)

    # Model: from scratch, or exactly where the last checkpoint left it.
    resumed = torch.load(checkpoint_path, map_location="cpu", weights_only=True) if checkpoint_path.exists() else None
    network = network_config(resumed["model_args"]) if resumed else config.network
    lookahead = network.lookahead
    utterances, heldout = load_corpus(Path(config.corpus), lookahead)
    model = Network(network).to(config.device)
    discriminator = Discriminator(network).to(config.device) if config.gan else None
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    d_optimizer = torch.optim.Adam(discriminator.parameters(), lr=config.lr, betas=(0.5, 0.999)) if config.gan else None
    step = 0
    if resumed:
        model.load_state_dict(resumed["model"])
        optimizer.load_state_dict(resumed["optimizer"])
        if config.gan and "discriminator" in resumed:
            discriminator.load_state_dict(resumed["discriminator"])
            d_optimizer.load_state_dict(resumed["d_optimizer"])
        step = resumed["step"]
        torch.set_rng_state(resumed["rng"]["torch"])
        rng.bit_generator.state = json.loads(resumed["rng"]["numpy"])
    else:
        model.set_feature_stats(*feature_stats(utterances, lookahead))
    validation_utterances = validation_set(heldout, config)
    best = held_out_position(best_path)
    speakers = sorted({u.speaker_id for u in utterances})
    print(f"{len(utterances)} training utterances from {len(speakers)} speakers, {len(heldout)} held out; "
          f"{parameter_count(model):,} parameters; {'resuming at' if resumed else 'starting from'} step {step}")

    def checkpoint(validation: dict | None, path: Path = checkpoint_path) -> None:
        training = {
            "steps": step, "seed": config.seed, "corpus": str(config.corpus), "utterances": len(utterances),
            "speakers": len(speakers), "heldout_utterances": len(heldout), "validation": validation,
        }
        state = {
            "model_args": asdict(network), "model": model.state_dict(), "optimizer": optimizer.state_dict(),
            "step": step, "config": json.dumps(asdict(config)), "training": training,
            "rng": {"torch": torch.get_rng_state(), "numpy": json.dumps(rng.bit_generator.state)},
        }
        if config.gan:
            state["discriminator"], state["d_optimizer"] = discriminator.state_dict(), d_optimizer.state_dict()
        save_checkpoint(path, state)

    # The loop.
    model.train()
    validation = None
    with open(out / LOG, "a") as log, tqdm(total=config.steps, initial=step, desc="training", unit="step", mininterval=1.0) as progress:
        started = time.time()
        while step < config.steps:
            lr = learning_rate(step, config)
            for group in optimizer.param_groups + (d_optimizer.param_groups if config.gan else []):
                group["lr"] = lr
            batch = sample_batch(utterances, config, lookahead, rng)
            loss, (out_, fake), terms = generator_losses(model, batch, config, discriminator)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
            optimizer.step()
            if config.gan:
                # Eq. 11: the discriminator learns real (training) motion from generated motion.
                context = discriminator_context(out_, lookahead)
                real = discriminator(batch["offsets"], batch["rotation"], *context)
                generated = discriminator(fake.detach(), out_.rotation[:, lookahead:].detach(), *context)
                d_loss = lsgan_losses(real, generated, batch["mask"])
                d_optimizer.zero_grad(set_to_none=True)
                d_loss.backward()
                torch.nn.utils.clip_grad_norm_(discriminator.parameters(), config.grad_clip)
                d_optimizer.step()
                terms["discriminator"] = float(d_loss.detach())
            step += 1
            progress.update()
            if step % config.log_every == 0 or step == config.steps:
                progress.set_postfix(loss=f"{terms['total']:.4f}", refresh=False)
                log.write(json.dumps({"step": step, "lr": lr, "train": terms, "seconds": round(time.time() - started, 1)}) + "\n")
                log.flush()
            if validation_utterances and (step % config.eval_every == 0 or step == config.steps):
                validation = evaluate(model, validation_utterances, config)
                log.write(json.dumps({"step": step, "validation": validation}) + "\n")
                log.flush()
                progress.write(f"step {step}: train {terms['total']:.4f}, held-out {validation['total']:.4f}")
                if validation["position"] < best:
                    best = validation["position"]
                    checkpoint(validation, best_path)
            if step % config.checkpoint_every == 0 or step == config.steps:
                checkpoint(validation)
    if not checkpoint_path.exists():
        checkpoint(validation)  # resumed at or beyond config.steps
    chosen = best_path if best_path.exists() else checkpoint_path
    voice = train_voice(utterances, heldout, config, lookahead) if config.voice_steps > 0 else None
    if config.export:
        chosen_step = torch.load(chosen, map_location="cpu", weights_only=True)["step"]
        why = ", the lowest held-out position loss" if chosen == best_path else ""
        gated = ", gated by the voice detector" if voice else ""
        print(f"exported {export(chosen, out / ONNX_FILE, voice)} (step {chosen_step}{why}{gated})")
    return chosen


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="puppet train", description="Train the audio → landmark network on a corpus folder.")
    defaults = TrainConfig()
    parser.add_argument("--corpus", required=True, help="corpus folder (manifest.jsonl, audio/, targets/)")
    parser.add_argument("--out", required=True, help="output folder: checkpoint.pt (resumed if present), log.jsonl, landmarks.onnx")
    parser.add_argument("--steps", type=int, default=defaults.steps, help=f"total training steps (default {defaults.steps})")
    parser.add_argument("--batch-size", type=int, default=defaults.batch_size)
    parser.add_argument("--sequence-frames", type=int, default=defaults.sequence_frames)
    parser.add_argument("--lr", type=float, default=defaults.lr)
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--eval-every", type=int, default=defaults.eval_every)
    parser.add_argument("--checkpoint-every", type=int, default=defaults.checkpoint_every)
    parser.add_argument("--no-gan", action="store_true", help="train without the adversarial loss")
    parser.add_argument("--no-feature-augment", action="store_true", help="train on the log-mels as they are (no recolouring, re-levelling, band masks)")
    parser.add_argument("--dropout", type=float, default=defaults.network.dropout, help=f"dropout between the content LSTM's layers (default {defaults.network.dropout})")
    parser.add_argument("--lookahead", type=int, default=defaults.network.lookahead, help=f"motion frames of future audio the network hears (default {defaults.network.lookahead}: 60 ms, for streaming; 15 = 300 ms, the paper's window, for offline rendering)")
    parser.add_argument("--tempo-changes", type=float, default=defaults.tempo_changes, help=f"share of training windows sped up or slowed down ({TEMPO_RANGE[0]}–{TEMPO_RANGE[1]}×; default {defaults.tempo_changes})")
    parser.add_argument("--phone-weight", type=float, default=defaults.phone_weight, help=f"weight of the auxiliary phone-classification loss (default {defaults.phone_weight}; 0: none)")
    parser.add_argument("--velocity-weight", type=float, default=defaults.velocity_weight, help=f"weight of the frame-to-frame velocity loss (default {defaults.velocity_weight})")
    parser.add_argument("--mouth-weight", type=float, default=defaults.mouth_weight, help=f"weight of the inner-mouth area loss (default {defaults.mouth_weight}; 0: none)")
    parser.add_argument("--voice-steps", type=int, default=defaults.voice_steps, help=f"steps training the voice detector exported with the network (default {defaults.voice_steps}; 0: none)")
    parser.add_argument("--threads", type=int, default=defaults.threads)
    parser.add_argument("--device", default=defaults.device, help="torch device, e.g. cuda (default cpu)")
    return parser


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    return TrainConfig(
        corpus=args.corpus, out=args.out, steps=args.steps, batch_size=args.batch_size,
        sequence_frames=args.sequence_frames, lr=args.lr, seed=args.seed, eval_every=args.eval_every,
        checkpoint_every=args.checkpoint_every, gan=not args.no_gan, threads=args.threads, device=args.device,
        feature_augment=not args.no_feature_augment, velocity_weight=args.velocity_weight, mouth_weight=args.mouth_weight, tempo_changes=args.tempo_changes,
        phone_weight=args.phone_weight, voice_steps=args.voice_steps,
        network=NetworkConfig(dropout=args.dropout, lookahead=args.lookahead, phone_classes=classifier_size(args.phone_weight)),
    )


def main(argv: list[str] | None = None) -> int:
    try:
        train(config_from_args(build_parser().parse_args(argv)))
    except PuppetError as error:
        print(f"puppet train: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
