"""The shipped lip-sync model as a user meets it: it talks on speech, rests in silence, and takes any audio."""
import numpy as np
import pytest

from puppet import audio, lipsync
from puppet.evaluate import lip_opening
from puppet.landmarks import face_scale

pytestmark = pytest.mark.skipif(not lipsync.has_model(), reason="no trained model in assets/models")
FPS = 25


def opening(demo, samples):
    frames = int(np.ceil(len(samples) / 16000 * FPS))
    motion = lipsync.learned_motion(samples, demo.rig.landmarks, FPS, frames)
    assert np.isfinite(motion.offsets).all() and np.isfinite(motion.rotation).all()
    assert np.abs(motion.offsets).max() < face_scale(demo.rig.landmarks)  # bounded: under one eye distance
    assert np.abs(np.degrees(motion.rotation)).max() < 15
    points = demo.rig.landmarks[None] + motion.offsets
    return (lip_opening(points) - lip_opening(demo.rig.landmarks[None])) / face_scale(demo.rig.landmarks)


def test_mouth_moves_with_speech_and_rests_in_silence(demo, demo_speech):
    speech = audio.load(demo_speech)
    silence = np.zeros(16000, np.float32)
    gap = opening(demo, np.concatenate([silence, speech, silence]))
    talking, quiet = gap[FPS + 5 : -FPS - 5], np.concatenate([gap[: FPS - 8], gap[-FPS + 8 :]])
    assert talking.max() > 0.12 and talking.std() > 0.03  # opens and closes while talking
    assert np.abs(quiet).max() < 0.03  # at rest in silence


@pytest.mark.parametrize("kind", ["noise", "clipped", "8k", "44k", "stereo"])
def test_any_input_gives_bounded_motion(demo, demo_speech, kind):
    speech = audio.load(demo_speech)
    rng = np.random.default_rng(0)
    if kind == "noise":
        samples = rng.normal(0, 0.3, 32000).astype(np.float32)
    elif kind == "clipped":
        samples = np.clip(speech * 20, -1, 1)
    else:
        from scipy.signal import resample_poly

        rate = {"8k": 8000, "44k": 44100, "stereo": 16000}[kind]
        samples = resample_poly(speech, rate, 16000).astype(np.float32) if rate != 16000 else speech
        if kind == "stereo":
            samples = np.stack([samples, samples * 0.5], axis=1)
        offsets, rotation = lipsync.shipped_predictor("offline").predict(samples, np.full(256, 1 / 16, np.float32), rate)
        assert np.isfinite(offsets).all() and np.abs(offsets).max() < 1.0
        return
    opening(demo, samples)
