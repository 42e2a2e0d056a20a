import subprocess
import sys
from dataclasses import asdict

import numpy as np
import pytest

from puppet import features
from puppet.predictor import Predictor, default_model

SECONDS = 7  # longer than the 256-frame attention window (5.12 s), so the window slides in the tests


def exported(folder, lookahead: int) -> Predictor:
    """A full-size network with random weights, exported as training exports it."""
    torch = pytest.importorskip("torch")
    from puppet.network import Network, NetworkConfig
    from puppet.train import export

    torch.manual_seed(0)
    net = Network(NetworkConfig(lookahead=lookahead))
    torch.nn.init.normal_(net.speaker_mlp[-1].weight, std=0.05)  # wake the zero-initialised speaker branch
    torch.save({"model_args": asdict(net.config), "model": net.state_dict()}, folder / "checkpoint.pt")
    return Predictor(export(folder / "checkpoint.pt", folder / "landmarks.onnx"))


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """The streaming layout: 60 ms of lookahead."""
    return exported(tmp_path_factory.mktemp("model"), 3)


@pytest.fixture(scope="module")
def offline_model(tmp_path_factory):
    """The offline layout: 300 ms of lookahead."""
    return exported(tmp_path_factory.mktemp("offline"), 15)


@pytest.fixture(scope="module")
def speech():
    """Vowel-like harmonic bursts with pauses: 16 kHz mono float32."""
    rng = np.random.default_rng(3)
    t = np.arange(SECONDS * features.SAMPLE_RATE) / features.SAMPLE_RATE
    voice = sum(np.sin(2 * np.pi * 140 * k * t + rng.uniform(0, 6)) / k for k in range(1, 15))
    envelope = np.clip(np.sin(2 * np.pi * 1.7 * t), 0, None) * (np.sin(2 * np.pi * 0.23 * t) > -0.3)
    return (0.2 * voice * envelope + 0.003 * rng.standard_normal(len(t))).astype(np.float32)


@pytest.fixture(scope="module")
def speaker():
    v = np.random.default_rng(4).standard_normal(256).astype(np.float32)
    return v / np.linalg.norm(v)


def test_predictor_imports_no_torch():
    code = "import sys, puppet.predictor; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


def test_frame_count_and_metadata(model, speech, speaker):
    for n in (0, 1, 159, 160, 320, 321, 16000, len(speech)):
        offsets, rotation = model.predict(speech[:n], speaker)
        assert offsets.shape == (features.motion_frame_count(n), 68, 3) and rotation.shape == (len(offsets), 3)
        assert offsets.dtype == np.float32 and rotation.dtype == np.float32
    assert 1000 * model.lookahead / model.fps + 1000 * features.WINDOW / 2 / features.SAMPLE_RATE <= 80 and model.fps == features.MOTION_FPS and model.n_landmarks == 68


@pytest.mark.parametrize("layout", ["model", "offline_model"])
@pytest.mark.parametrize("seed", [0, 1])
def test_stream_equals_offline(request, layout, speech, speaker, seed):
    model = request.getfixturevalue(layout)
    offline = model.predict(speech, speaker)
    rng = np.random.default_rng(seed)
    stream, parts, position = model.stream(speaker), [], 0
    while position < len(speech):
        size = int(rng.choice([0, 1, 17, 160, 333, 800, 1600, 4000]))
        parts.append(stream.push(speech[position : position + size]))
        position += size
    parts.append(stream.finish())
    offsets = np.concatenate([p[0] for p in parts])
    rotation = np.concatenate([p[1] for p in parts])
    assert offsets.shape == offline[0].shape
    np.testing.assert_allclose(offsets, offline[0], atol=1e-4, rtol=0)
    np.testing.assert_allclose(rotation, offline[1], atol=1e-4, rtol=0)


@pytest.mark.parametrize("layout", ["model", "offline_model"])
def test_stream_latency(request, layout, speaker):
    """A frame comes out once its audio and the lookahead after it have arrived, never later."""
    model = request.getfixturevalue(layout)
    stream = model.stream(speaker)
    emitted = 0
    for n in range(0, 16000, 160):
        emitted += len(stream.push(np.zeros(160, np.float32))[0])
        samples = n + 160
        expected = max(0, ((samples - features.WINDOW // 2) // features.HOP + 1) // 2 - model.lookahead)
        assert emitted == expected


@pytest.mark.parametrize("kind", ["silence", "white noise", "clipped", "nan", "8 kHz", "44.1 kHz", "stereo"])
def test_hostile_input_gives_bounded_motion(model, speech, speaker, kind):
    rng = np.random.default_rng(5)
    samples, rate = speech[: 3 * features.SAMPLE_RATE], features.SAMPLE_RATE
    if kind == "silence":
        samples = np.zeros_like(samples)
    elif kind == "white noise":
        samples = rng.uniform(-1, 1, len(samples)).astype(np.float32)
    elif kind == "clipped":
        samples = np.clip(samples * 50, -1, 1)
    elif kind == "nan":
        samples = samples.copy()
        samples[::7] = np.nan
        samples[::11] = np.inf
    elif kind == "8 kHz":
        samples, rate = samples[::2], 8000
    elif kind == "44.1 kHz":
        samples, rate = np.interp(np.arange(3 * 44100) / 44100, np.arange(len(samples)) / 16000, samples), 44100
    elif kind == "stereo":
        samples = np.stack([samples, -0.5 * samples], axis=1)
    offsets, rotation = model.predict(samples, speaker, sample_rate=rate)
    assert len(offsets) == features.motion_frame_count(3 * features.SAMPLE_RATE)
    assert np.isfinite(offsets).all() and np.isfinite(rotation).all()
    assert np.abs(offsets).max() < 1.0 and np.abs(rotation).max() < 0.8


@pytest.mark.parametrize("kind", ["streaming", "offline"])
def test_shipped_model_closes_the_mouth_in_silence(speaker, kind):
    """With each trained model: silence → inner lips together, head near still."""
    if not default_model(kind).exists():
        pytest.skip("no trained model in assets/models yet")
    from puppet.landmarks import INNER_LIP_PAIRS

    predictor = Predictor(default_model(kind))
    offsets, _ = predictor.predict(np.zeros(2 * features.SAMPLE_RATE, np.float32), speaker)
    upper, lower = [p[0] for p in INNER_LIP_PAIRS], [p[1] for p in INNER_LIP_PAIRS]
    opening = offsets[:, lower, 1] - offsets[:, upper, 1]  # IOD units, y down: > 0 opens the mouth
    assert np.abs(opening).max() < 0.03


def test_an_ensemble_is_the_mean_of_its_networks_with_their_own_lookaheads(model, offline_model, speech, speaker):
    """Two networks hearing 60 and 300 ms ahead: the ensemble gives each clip frame the mean of their frames."""
    from puppet.predictor import Ensemble

    answers = [predictor.predict(speech, speaker) for predictor in (model, offline_model)]
    offsets, rotation = Ensemble((model, offline_model)).predict(speech, speaker)
    assert offsets.shape == answers[0][0].shape and offsets.dtype == np.float32
    np.testing.assert_allclose(offsets, (answers[0][0] + answers[1][0]) / 2, atol=1e-6)
    np.testing.assert_allclose(rotation, (answers[0][1] + answers[1][1]) / 2, atol=1e-6)
    assert not np.allclose(answers[0][0], answers[1][0], atol=1e-3)  # they differ, so the mean is a test
