import numpy as np
import pytest

from puppet import nonspeech


def spectral_flatness(clip):
    power = np.abs(np.fft.rfft(clip * np.hanning(len(clip)))) ** 2 + 1e-12
    return float(np.exp(np.log(power).mean()) / power.mean())


@pytest.mark.parametrize("kind", nonspeech.KINDS)
def test_every_kind_is_a_finite_clip_of_the_asked_length(kind):
    rng = np.random.default_rng(0)
    for _ in range(5):
        clip = nonspeech._normalised(getattr(nonspeech, kind)(16000, rng))
        assert clip.shape == (16000,) and clip.dtype == np.float32 and np.isfinite(clip).all()
        assert np.abs(clip).max() == pytest.approx(0.5) and clip.std() > 1e-3


def test_a_seed_makes_the_same_sounds_and_another_seed_others():
    first = [nonspeech.sound(2.0, np.random.default_rng(3)) for _ in range(2)]
    np.testing.assert_array_equal(first[0], first[1])
    assert not np.array_equal(first[0], nonspeech.sound(2.0, np.random.default_rng(4)))
    assert len(first[0]) == 32000


def test_music_has_notes_and_noise_has_none(monkeypatch):
    """Synthesised music's spectrum is peaked at its notes' partials; white noise's is flat."""
    monkeypatch.setattr(nonspeech, "soundfont", lambda: None)
    rng = np.random.default_rng(1)
    music = [spectral_flatness(nonspeech.music(32000, rng)) for _ in range(5)]
    noise = spectral_flatness(np.random.default_rng(2).normal(0, 1, 32000))
    assert max(music) < 0.2 * noise


def test_mains_hum_sits_on_its_harmonics():
    seed = next(seed for seed in range(100) if np.random.default_rng(seed).random() < 0.2)  # a seed that draws hum
    spectrum = np.abs(np.fft.rfft(nonspeech.noise(16000, np.random.default_rng(seed))))  # 1 Hz bins
    peak = int(spectrum.argmax())
    assert peak % 50 == 0 or peak % 60 == 0


def read_midi(data: bytes) -> tuple[int, list[tuple[int, int, int]]]:
    """(ticks per beat, [(tick, status, key)] of the note events) of a type-0 file."""
    assert data[:4] == b"MThd" and data[14:18] == b"MTrk"
    track, at, tick, events = data[22:], 0, 0, []

    def varint():
        nonlocal at
        value = 0
        while True:
            byte = track[at]
            at += 1
            value = value << 7 | byte & 0x7F
            if byte < 0x80:
                return value

    while at < len(track):
        tick += varint()
        status = track[at]
        if status == 0xFF:
            kind, at = track[at + 1], at + 2
            length = varint()
            at += length
            if kind == 0x2F:
                break
        elif status & 0xF0 == 0xC0:
            at += 2
        else:
            events.append((tick, status, track[at + 1]))
            at += 3
    assert at == len(track)
    return int.from_bytes(data[12:14], "big"), events


def test_the_midi_score_holds_every_note_on_and_off():
    bpm, notes = nonspeech._score(4.0, np.random.default_rng(0))
    ticks, events = read_midi(nonspeech._midi(bpm, notes, (0, 33, 73)))
    ons = sorted((tick, status & 0x0F, key) for tick, status, key in events if status & 0xF0 == 0x90)
    offs = [event for event in events if event[1] & 0xF0 == 0x80]
    assert ticks == nonspeech.TICKS and len(ons) == len(offs) == len(notes)
    assert ons == sorted((int(start * ticks), channel, key) for start, _, channel, key, _ in notes)
    assert [tick for tick, _, _ in events] == sorted(tick for tick, _, _ in events)


@pytest.mark.skipif(nonspeech.soundfont() is None, reason="no fluidsynth and General MIDI soundfont here")
def test_sampled_instruments_play_the_score():
    clip = nonspeech.sampled_music(48000, np.random.default_rng(0), nonspeech.soundfont())
    assert clip is not None and clip.shape == (48000,) and np.isfinite(clip).all()
    assert np.sqrt(np.mean(clip[:16000] ** 2)) > 1e-3  # it sounds from the start
