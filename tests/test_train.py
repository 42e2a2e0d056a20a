import json
import shutil
import wave
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from puppet import features
from puppet.network import LOOKAHEAD, NetworkConfig
from puppet.train import (
    CHECKPOINT,
    LOG,
    ONNX_FILE,
    PHONE_CLASSES,
    VOICE_FILE,
    TrainConfig,
    export,
    load_network,
    train,
)

VOICES = {"low": 120.0, "high": 210.0, "other": 160.0}  # speaker → fundamental (Hz); "other" is held out
LOWER_LIP_AND_CHIN = [7, 8, 9, 56, 57, 58, 65, 66, 67]
# The paper's layout at a fraction of the width, so that a few CPU steps show learning quickly.
TINY = NetworkConfig(content_hidden=64, content_mlp=(128, 64), content_code=16, speaker_reduced=32, window=64, speaker_mlp=64,
                     phone_classes=len(PHONE_CLASSES))


def synthetic_utterance(rng, f0, seconds):
    """Harmonic bursts between silences, targets whose mouth opens with the burst envelope, and phones:
    each burst an "AA", silence between."""
    n = int(seconds * features.SAMPLE_RATE)
    envelope = np.zeros(n, np.float32)
    position = int(rng.uniform(0.1, 0.3) * features.SAMPLE_RATE)
    while position < n - 4000:
        length = int(rng.uniform(0.12, 0.35) * features.SAMPLE_RATE)
        envelope[position : position + length] = np.hanning(length)[: n - position] * rng.uniform(0.5, 1.0)
        position += length + int(rng.uniform(0.08, 0.3) * features.SAMPLE_RATE)
    t = np.arange(n) / features.SAMPLE_RATE
    voice = sum(np.sin(2 * np.pi * f0 * k * t) / k for k in range(1, 12))
    samples = (0.25 * envelope * voice).astype(np.float32)
    frames = features.motion_frame_count(n)
    centres = np.minimum(np.arange(frames) * 320 + 80, n - 1)
    offsets = np.zeros((frames, 68, 3), np.float32)
    offsets[:, LOWER_LIP_AND_CHIN, 1] = 0.3 * envelope[centres, None]
    rotation = np.zeros((frames, 3), np.float32)
    rotation[:, 0] = 0.05 * np.sin(np.arange(frames) / 25 + f0)
    voiced = np.r_[False, envelope > 0, False]
    edges = np.flatnonzero(voiced[1:] != voiced[:-1]) / features.SAMPLE_RATE  # burst starts and ends, seconds
    times = [0.0, *edges, n / features.SAMPLE_RATE]
    phones = [{"phone": "AA" if i % 2 else "SIL", "start": a, "end": b} for i, (a, b) in enumerate(zip(times, times[1:])) if b > a]
    return samples, offsets, rotation, phones


def make_corpus(folder, seed=0, per_voice=3):
    """A corpus folder as puppet.corpus and the labellers write it (plus cached speaker embeddings)."""
    rng = np.random.default_rng(seed)
    for sub in ("audio", "targets", "embeddings", "phones"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    lines = []
    for speaker, f0 in VOICES.items():
        embedding = rng.standard_normal(256).astype(np.float32)
        embedding /= np.linalg.norm(embedding)
        for i in range(1 if speaker == "other" else per_voice):
            uid = f"{speaker}{i:02d}"
            samples, offsets, rotation, phones = synthetic_utterance(rng, f0, rng.uniform(1.5, 2.5))
            with wave.open(str(folder / "audio" / f"{uid}.wav"), "wb") as f:
                f.setnchannels(1), f.setsampwidth(2), f.setframerate(features.SAMPLE_RATE)
                f.writeframes((samples * 32767).astype("<i2").tobytes())
            np.savez(folder / "targets" / f"{uid}.npz", offsets=offsets, rotation=rotation, fps=50)
            np.save(folder / "embeddings" / f"{uid}.npy", embedding)
            (folder / "phones" / f"{uid}.json").write_text(json.dumps(phones))
            heldout = speaker == "other"
            lines.append(json.dumps({"id": uid, "text": "bursts", "speaker": speaker, "heldout": heldout, "seconds": len(samples) / 16000}))
    lines.append(json.dumps({"id": "unlabelled", "text": "x", "speaker": "low", "heldout": False, "seconds": 1.0}))
    (folder / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    return folder


def log_lines(out):
    return [json.loads(line) for line in (out / LOG).read_text().splitlines()]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    config = TrainConfig(
        corpus=str(make_corpus(root / "corpus")), out=str(root / "out"), batch_size=8, sequence_frames=64,
        lr=3e-3, warmup_steps=5, steps=30, eval_every=15, checkpoint_every=10, log_every=1, gan=False, export=False,
        network=TINY, threads=1, phone_weight=0.02, voice_steps=40, voice_sounds=4,
    )
    train(config)
    return config


def test_loss_falls(run):
    lines = [line for line in log_lines(Path(run.out)) if "train" in line]
    first = np.mean([line["train"]["position"] for line in lines[:3]])
    last = np.mean([line["train"]["position"] for line in lines[-3:]])
    assert [line["step"] for line in lines] == list(range(1, 31))
    assert last < 0.5 * first
    first_phone = np.mean([line["train"]["phone"] for line in lines[:3]])
    assert np.mean([line["train"]["phone"] for line in lines[-3:]]) < 0.9 * first_phone  # from ln 40 ≈ 3.7 (weight 0.02)
    validation = [line for line in log_lines(Path(run.out)) if "validation" in line]
    assert [line["step"] for line in validation] == [15, 30]


def test_resume_continues(run, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(run.out, out)
    train(replace(run, out=str(out), steps=34))
    steps = [line["step"] for line in log_lines(out) if "train" in line]
    assert steps == list(range(1, 35))
    _, checkpoint = load_network(out / CHECKPOINT)
    assert checkpoint["step"] == 34
    assert Path(run.out, CHECKPOINT).exists()


def test_gan_step(tmp_path):
    corpus = make_corpus(tmp_path / "corpus", per_voice=1)
    config = TrainConfig(corpus=str(corpus), out=str(tmp_path / "out"), batch_size=2, sequence_frames=32, steps=2, log_every=1, gan=True, export=False, network=TINY, threads=1, voice_steps=0)
    train(config)
    lines = [line for line in log_lines(tmp_path / "out") if "train" in line]
    assert all(np.isfinite(line["train"]["discriminator"]) and np.isfinite(line["train"]["adversarial"]) for line in lines)


def test_export_matches_torch(run, tmp_path):
    import onnxruntime as ort

    from puppet.predictor import Predictor, audio_steps
    from puppet.train import read_wav

    path = export(Path(run.out, CHECKPOINT), tmp_path / ONNX_FILE)
    model, _ = load_network(Path(run.out, CHECKPOINT))
    samples = read_wav(Path(run.corpus, "audio", "low00.wav"))
    steps = audio_steps(samples, model.config.lookahead)
    speaker = np.load(Path(run.corpus, "embeddings", "low00.npy"))
    with torch.no_grad():
        want = model.run(torch.from_numpy(steps[None]), torch.from_numpy(speaker[None]), model.initial_state())
    predictor = Predictor(path)
    offsets, rotation = predictor.predict(samples, speaker)
    lookahead = model.config.lookahead
    np.testing.assert_allclose(offsets, want.offsets[0, lookahead:].numpy(), atol=1e-4, rtol=0)
    np.testing.assert_allclose(rotation, want.rotation[0, lookahead:].numpy(), atol=1e-4, rtol=0)
    meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    assert json.loads(meta["feature_spec"]) == json.loads(json.dumps(features.SPEC))
    assert meta["n_landmarks"] == "68" and meta["lookahead_frames"] == str(LOOKAHEAD) and float(meta["motion_fps"]) == 50
    assert json.loads(meta["training"])["steps"] == 30
    assert b"phone_head" not in path.read_bytes()  # the phone classifier is for training only


def test_frame_phones_names_the_phone_at_each_frame_centre():
    from puppet.train import frame_phones

    rows = [{"phone": "SIL", "start": 0.0, "end": 0.25}, {"phone": "P", "start": 0.25, "end": 0.28},
            {"phone": "IY", "start": 0.28, "end": 0.4}]
    classes = [PHONE_CLASSES[i] for i in frame_phones(rows, 22)]  # frame j is centred at (j + 0.5) × 20 ms
    assert classes == ["SIL"] * 12 + ["P"] * 2 + ["IY"] * 6 + ["SIL"] * 2  # silence past the last phone


def test_feature_augmentation_recolours_windows_but_keeps_silence_and_shape():
    from puppet.predictor import SILENCE
    from puppet.train import augment_steps

    rng = np.random.default_rng(0)
    steps = rng.uniform(-4.0, -1.0, (50, 160)).astype(np.float32)
    steps[40:] = SILENCE
    first, second = augment_steps(steps, np.random.default_rng(1)), augment_steps(steps, np.random.default_rng(2))
    assert first.shape == steps.shape and first.dtype == np.float32
    assert np.all(first[40:] == SILENCE) and first.min() >= SILENCE
    assert 0.05 < np.abs(first[:40] - steps[:40]).mean() < 1.5
    assert not np.allclose(first, second)
    np.testing.assert_array_equal(first, augment_steps(steps, np.random.default_rng(1)))


def test_a_silence_tail_silences_the_audio_and_brings_the_mouth_to_rest():
    from puppet.predictor import SILENCE
    from puppet.train import REST_FRAMES, silence_tail

    rng = np.random.default_rng(0)
    steps = rng.uniform(-4, -1, (40 + 3, 160)).astype(np.float32)
    offsets = rng.normal(0, 0.1, (40, 68, 3)).astype(np.float32)
    rotation = rng.normal(0, 0.1, (40, 3)).astype(np.float32)
    before = offsets.copy()
    silence_tail(steps, offsets, rotation, 40, 20)
    assert np.all(steps[20:] == SILENCE) and np.all(steps[:20] > SILENCE)
    np.testing.assert_array_equal(offsets[:20], before[:20])
    assert np.all(offsets[20 + REST_FRAMES - 1 :] == 0)
    assert np.all(np.abs(offsets[20]) <= np.abs(before[19]) + 1e-7)
    assert np.all(rotation[20:] == rotation[19])


@pytest.mark.parametrize("kind", ["streaming", "offline"])
def test_recipes_match_the_shipped_models(kind):
    """`puppet train` rebuilds each shipped model with the lookahead and the phone classifier (or none)
    it was trained with."""
    from puppet.predictor import Predictor, default_model
    from puppet.train import recipe

    if not default_model(kind).exists():
        pytest.skip("no trained model in assets/models yet")
    config = recipe(kind, corpus="corpus", out="runs")
    shipped = Predictor(default_model(kind))
    assert shipped.lookahead == config.network.lookahead
    trained = json.loads(shipped.metadata["network"])  # the NetworkConfig it was trained with
    assert trained.get("phone_classes", 0) == config.network.phone_classes and trained["dropout"] == config.network.dropout
    assert config.network.lookahead * 1000 // features.MOTION_FPS <= (60 if kind == "streaming" else 300)


def test_a_stretched_window_keeps_sound_and_mouth_together():
    """A window played twice as fast: an event in the audio and its mouth pose land on the same
    (halved) frame; rate 1 is the window itself."""
    from puppet.predictor import SILENCE
    from puppet.train import Utterance, stretched_window

    frames, lookahead = 200, 3
    steps = np.full((frames + lookahead, 160), SILENCE, np.float32)
    offsets = np.zeros((frames, 68, 3), np.float32)
    steps[120:130] = -1.0  # a loud burst at motion frames 120–129 …
    offsets[120:130, 66, 1] = 0.3  # … with the mouth open
    phones = np.zeros(frames, np.int64)
    phones[120:130] = PHONE_CLASSES.index("AA")
    u = Utterance("a", "s", steps, offsets, np.zeros((frames, 3), np.float32), np.zeros(256, np.float32), phones)
    same = stretched_window(u, 20, 100, lookahead, 1.0)
    np.testing.assert_array_equal(same[0], steps[20:123])
    fast, mouth, rotation, said = stretched_window(u, 20, 60, lookahead, 2.0)
    assert fast.shape == (63, 160) and mouth.shape == (60, 68, 3) and rotation.shape == (60, 3) and said.shape == (60,)
    loud = np.flatnonzero(fast.max(axis=1) > -3)
    open_ = np.flatnonzero(mouth[:, 66, 1] > 0.1)
    assert abs(loud.mean() - 52) < 1 and abs(open_.mean() - 52) < 1 and abs(len(open_) - 5) <= 1  # (120 − 20) / 2 = 50 on
    said_aa = np.flatnonzero(said == PHONE_CLASSES.index("AA"))
    assert abs(said_aa.mean() - 52) < 1 and abs(len(said_aa) - 5) <= 1  # the phone labels move with them


def test_an_utterance_without_its_phones_counts_as_not_labelled_yet(tmp_path):
    from puppet.train import load_corpus

    corpus = make_corpus(tmp_path / "corpus", per_voice=2)
    before, _ = load_corpus(corpus, 3)
    (corpus / "phones" / "low00.json").unlink()  # labelling stopped between targets and phones
    after, _ = load_corpus(corpus, 3)
    assert len(after) == len(before) - 1 and "low00" not in {u.id for u in after}


def test_the_checkpoint_with_the_lowest_held_out_loss_is_kept_and_exported(run, tmp_path):
    from puppet.predictor import Predictor
    from puppet.train import BEST_CHECKPOINT

    validation = [line for line in log_lines(Path(run.out)) if "validation" in line]
    best = min(validation, key=lambda line: line["validation"]["position"])
    _, kept = load_network(Path(run.out, BEST_CHECKPOINT))
    assert kept["step"] == best["step"]
    assert kept["training"]["validation"] == best["validation"]
    out = tmp_path / "out"
    shutil.copytree(run.out, out)
    worse = torch.load(out / BEST_CHECKPOINT, weights_only=True)
    worse["training"]["validation"]["position"] = 1e9  # any later evaluation beats it
    torch.save(worse, out / BEST_CHECKPOINT)
    chosen = train(replace(run, out=str(out), steps=40, eval_every=5, export=True))
    assert chosen == out / BEST_CHECKPOINT
    _, kept = load_network(chosen)
    assert kept["step"] in (35, 40) and kept["training"]["validation"]["position"] < 1e9
    assert json.loads(Predictor(out / ONNX_FILE).metadata["training"])["steps"] == kept["step"]


def test_voice_labels_bridge_short_pauses_only():
    from puppet.train import SILENT_CLASS, VOICE_PAUSE_FRAMES, voice_labels

    said = PHONE_CLASSES.index("AA")
    phones = np.full(60, SILENT_CLASS)
    phones[5:10] = phones[12:20] = phones[20 + VOICE_PAUSE_FRAMES + 1 : 40] = said  # a 2-frame and a 16-frame pause
    labels = voice_labels(phones)
    np.testing.assert_array_equal(np.flatnonzero(labels), np.r_[5:20, 36:40])


def test_a_sound_is_mixed_under_speech_at_the_asked_ratio():
    from puppet.train import mix

    rng = np.random.default_rng(0)
    speech, sound = rng.uniform(-3, -1, (50, 160)).astype(np.float32), rng.uniform(-4, -2, (50, 160)).astype(np.float32)

    def power(steps):
        return np.maximum(10.0**steps - features.LOG_FLOOR, 0).mean()

    mixed = mix(speech, sound, 10.0)
    assert power(mixed) == pytest.approx(1.1 * power(speech), rel=1e-3)  # the sound adds a tenth
    silence = np.full_like(sound, np.log10(features.LOG_FLOOR))
    alone = mix(silence, sound, 0.0, reference=power(speech))  # a lone sound as loud as the speech
    assert power(alone) == pytest.approx(power(speech), rel=1e-3)


def test_the_voice_detector_learns_and_its_gate_is_exported(run, tmp_path):
    """Its loss falls; exported with the network, the offsets are scaled by voice_weight and onnxruntime
    agrees with torch; the predictor carries its state, so a stream still equals the whole clip."""
    from puppet.network import GatedNetwork, voice_weight
    from puppet.predictor import Predictor, audio_steps
    from puppet.train import load_voice, read_wav

    losses = [line["loss"] for line in log_lines(Path(run.out)) if "voice_step" in line]
    assert len(losses) == 40 and np.mean(losses[-5:]) < 0.8 * np.mean(losses[:5])
    path = export(Path(run.out, CHECKPOINT), tmp_path / ONNX_FILE, Path(run.out, VOICE_FILE))
    network, _ = load_network(Path(run.out, CHECKPOINT))
    detector, state = load_voice(Path(run.out, VOICE_FILE))
    assert state["step"] == 40 and 0 <= state["validation"]["accuracy"] <= 1
    samples = read_wav(Path(run.corpus, "audio", "low00.wav"))
    speaker = np.load(Path(run.corpus, "embeddings", "low00.npy"))
    steps = torch.from_numpy(audio_steps(samples, network.config.lookahead)[None])
    with torch.no_grad():
        plain = network.run(steps, torch.from_numpy(speaker[None]), network.initial_state()).offsets
        gated = GatedNetwork(network, detector)(steps, torch.from_numpy(speaker[None]), *network.initial_state(), detector.initial_state())[0]
        weight = voice_weight(detector(steps, detector.initial_state())[0])
    torch.testing.assert_close(gated, plain * weight[..., None, None])
    predictor = Predictor(path)
    lookahead = network.config.lookahead
    offsets, _ = predictor.predict(samples, speaker)
    np.testing.assert_allclose(offsets, gated[0, lookahead:].numpy(), atol=1e-4, rtol=0)
    stream = predictor.stream(speaker)
    pieces = [stream.push(samples[i : i + 700])[0] for i in range(0, len(samples), 700)] + [stream.finish()[0]]
    np.testing.assert_allclose(np.concatenate(pieces), offsets, atol=1e-5, rtol=0)
    assert "voice_detector" in predictor.metadata
