import numpy as np

from puppet import features as f


def test_shapes_and_frame_rule():
    for n in [0, 1, 159, 160, 16000]:
        assert f.log_mel(np.zeros(n, np.float32)).shape == (f.frame_count(n), f.N_MELS)
    assert f.frame_count(16000) == 101 and f.motion_frame_count(16000) == 51


def test_a_tone_lights_the_right_mel_band():
    t = np.arange(16000) / f.SAMPLE_RATE
    mel = f.log_mel(0.5 * np.sin(2 * np.pi * 1000 * t).astype(np.float32))
    centres = np.linspace(0, f.SAMPLE_RATE / 2, f.N_FFT // 2 + 1) @ (f.mel_filters() / f.mel_filters().sum(1, keepdims=True)).T
    assert abs(centres[int(np.argmax(mel[50]))] - 1000) < 120


def test_silence_is_the_floor_and_garbage_is_finite():
    assert np.allclose(f.log_mel(np.zeros(1600, np.float32)), np.log10(f.LOG_FLOOR))
    noisy = np.array([np.nan, np.inf, -np.inf, 5.0] * 400, np.float32)
    assert np.isfinite(f.log_mel(noisy)).all()


def test_filters_have_unit_area_in_hz():
    hz_per_bin = f.SAMPLE_RATE / f.N_FFT
    areas = f.mel_filters().sum(axis=1) * hz_per_bin
    assert np.allclose(areas[2:-2], 1.0, rtol=0.15)
