"""Voice augmentation: speakers sound shifted by the stated ratios, rooms and noise are as loud as asked,
timing changes are exact and shared by the clean copy, and a seed gives the same result."""
import numpy as np
import pytest

from puppet import augment
from puppet.augment import RATE, Settings

F0 = 150.0  # Hz: fundamental of the test voice


def harmonic_tone(seconds=1.0, f0=F0, harmonics=12):
    """(N,) float32 buzz with harmonics falling 6 dB/octave, peak about 0.5: a crude vowel."""
    t = np.arange(round(seconds * RATE)) / RATE
    tone = sum(np.sin(2 * np.pi * f0 * k * t) / k for k in range(1, harmonics + 1))
    return (0.5 * tone / np.abs(tone).max()).astype(np.float32)


def fundamental(samples):
    """Strongest spectral peak between 60 and 500 Hz, to 0.25 Hz, away from the clip's edges."""
    middle = samples[len(samples) // 8 : -len(samples) // 8]
    spectrum = np.abs(np.fft.rfft(middle * np.hanning(len(middle)), 4 * RATE))
    lo, hi = 60 * 4, 500 * 4
    return (lo + np.argmax(spectrum[lo:hi])) / 4


def centroid(samples):
    spectrum = np.abs(np.fft.rfft(samples)) ** 2
    return float(np.sum(np.fft.rfftfreq(len(samples), 1 / RATE) * spectrum) / np.sum(spectrum))


def band_energy(samples, lo, hi):
    spectrum = np.abs(np.fft.rfft(samples)) ** 2
    f = np.fft.rfftfreq(len(samples), 1 / RATE)
    return float(np.sum(spectrum[(f >= lo) & (f < hi)]))


@pytest.mark.parametrize("ratio", [0.8, 1.25, 1.5])
def test_pitch_shift_moves_the_fundamental_by_the_ratio(ratio):
    shifted = augment.shift_pitch(harmonic_tone(), ratio)
    assert len(shifted) == RATE
    assert fundamental(shifted) == pytest.approx(F0 * ratio, rel=0.01)


def test_formant_shift_moves_the_spectrum_but_not_the_fundamental():
    tone = harmonic_tone()
    brighter = augment.shift_formants(tone, 1.2)
    assert len(brighter) == len(tone)
    assert fundamental(brighter) == pytest.approx(F0, rel=0.01)
    assert centroid(brighter) > 1.1 * centroid(tone)
    assert centroid(augment.shift_formants(tone, 0.85)) < 0.95 * centroid(tone)


@pytest.mark.parametrize("tempo", [0.85, 1.0, 1.2])
def test_tempo_scales_the_length_exactly_and_keeps_the_pitch(tempo):
    tone = harmonic_tone()
    faster = augment.stretch(tone, tempo)
    assert len(faster) == round(len(tone) / tempo)
    assert fundamental(faster) == pytest.approx(F0, rel=0.01)


@pytest.mark.parametrize("kind", augment.NOISE_KINDS)
@pytest.mark.parametrize("snr_db", [10.0, 25.0, 40.0])
def test_noise_is_added_at_the_requested_snr(kind, snr_db):
    tone = harmonic_tone()
    noisy = augment.add_noise(tone, snr_db, kind, np.random.default_rng(0))
    noise = noisy.astype(np.float64) - tone
    measured = 10 * np.log10(np.mean(tone.astype(np.float64) ** 2) / np.mean(noise**2))
    assert measured == pytest.approx(snr_db, abs=1.0)


def test_reverb_lengthens_the_decay_more_in_larger_rooms():
    burst = np.zeros(RATE, np.float32)
    burst[: RATE // 10] = harmonic_tone(0.1)
    tail = slice(RATE // 10 + RATE // 20, RATE // 2)  # from 50 ms after the burst stops

    def tail_energy(rt60):
        wet = augment.reverberate(burst, rt60, 0.5, np.random.default_rng(0))
        return float(np.sum(wet[tail].astype(np.float64) ** 2))

    assert tail_energy(0.0) == 0.0
    assert tail_energy(0.6) > 10 * tail_energy(0.15) > 0


def test_telephone_band_removes_lows_and_highs():
    noise = np.random.default_rng(0).standard_normal(RATE).astype(np.float32) * 0.1
    phone = augment.microphone(noise, Settings(low_cut_hz=300, high_cut_hz=3400))
    assert band_energy(phone, 50, 150) < 0.05 * band_energy(noise, 50, 150)
    assert band_energy(phone, 6000, 8000) < 0.05 * band_energy(noise, 6000, 8000)
    assert band_energy(phone, 800, 2000) > 0.7 * band_energy(noise, 800, 2000)


def test_level_sets_the_peak():
    assert np.abs(augment.set_level(harmonic_tone(), -20.0)).max() == pytest.approx(0.1, rel=1e-3)


def test_every_transform_keeps_length_and_stays_finite_and_in_range():
    tone = harmonic_tone() * 1.9  # nearly full scale
    rng = np.random.default_rng(0)
    outputs = [
        augment.shift_pitch(tone, 1.4),
        augment.shift_formants(tone, 0.8),
        augment.reverberate(tone, 0.6, 0.6, rng),
        augment.add_noise(tone, 10.0, "pink", rng),
        augment.microphone(tone, Settings(low_cut_hz=200, high_cut_hz=4000, tilt_db=3, peak_hz=2000, peak_db=6)),
        augment.set_level(tone, -3.0),
    ]
    for out in outputs:
        assert out.dtype == np.float32 and len(out) == len(tone)
        assert np.all(np.isfinite(out))
    for _ in range(10):  # whole chains, at the loudest level drawn
        settings = augment.draw(rng, 1.5, 1.18)
        clean, heard = augment.apply(tone, settings, rng)
        assert len(clean) == len(heard) == round(len(tone) / settings.tempo)
        for out in (clean, heard):
            assert np.all(np.isfinite(out)) and np.abs(out).max() <= 1.0


def test_clean_copy_has_the_same_speaker_and_timing_as_the_training_copy():
    settings = Settings(pitch=1.3, formant=1.15, tempo=0.9)  # no room, noise or microphone
    clean, heard = augment.apply(harmonic_tone(), settings, np.random.default_rng(0))
    np.testing.assert_allclose(clean, heard, atol=1e-6)
    assert fundamental(clean) == pytest.approx(F0 * 1.3, rel=0.01)

    noisy = Settings(pitch=1.3, formant=1.15, tempo=0.9, rt60=0.3, wet=0.3, noise="white", snr_db=30, level_dbfs=-3)
    clean2, heard2 = augment.apply(harmonic_tone(), noisy, np.random.default_rng(0))
    np.testing.assert_array_equal(clean, clean2)
    assert np.corrcoef(clean2, heard2)[0, 1] > 0.8  # the same sound, in the same place


def test_same_seed_same_result_and_draws_stay_in_their_ranges():
    tone = harmonic_tone()
    runs = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        runs.append(augment.apply(tone, augment.draw(rng), rng))
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    other = np.random.default_rng(8)
    assert not np.array_equal(runs[0][1], augment.apply(tone, augment.draw(other), other)[1])

    draws = [augment.draw(np.random.default_rng(i), 0.8, 0.9) for i in range(200)]
    assert all(0.85 <= d.tempo <= 1.2 and -35 <= d.level_dbfs <= -3 and 0 <= d.rt60 <= 0.6 for d in draws)
    assert all(d.pitch == 0.8 and d.formant == 0.9 for d in draws)
    assert any(d.noise is None for d in draws) and any(d.rt60 == 0 for d in draws)
    assert any((d.low_cut_hz, d.high_cut_hz) == augment.TELEPHONE_BAND for d in draws)
