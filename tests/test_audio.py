"""Audio decoding: every common format, rate and layout reads the same; bad files become PuppetError."""
import wave

import av
import cv2
import numpy as np
import pytest
from conftest import shared

from puppet import audio
from puppet.errors import PuppetError

TONE_HZ = 440.0
SECONDS = 0.5
AMPLITUDE = 0.5  # -6 dBFS
TOLERANCE = 0.04  # seconds: one 25 fps frame, the step motion is computed at


def write_tone(path, codec, rate, channels, seconds=SECONDS, amplitude=AMPLITUDE, right=None, options=None):
    """Encode a TONE_HZ sine with PyAV, as a user's recorder would; `right` overrides the right channel."""
    t = np.arange(round(seconds * rate)) / rate
    tone = (amplitude * np.sin(2 * np.pi * TONE_HZ * t)).astype(np.float32)
    planes = [tone] if channels == 1 else [tone, tone if right is None else right(t).astype(np.float32)]
    layout = "mono" if channels == 1 else "stereo"
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=rate, layout=layout, options=options or {})
        frame = av.AudioFrame.from_ndarray(np.stack(planes), format="fltp", layout=layout)
        frame.sample_rate, frame.pts = rate, 0
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return path


def dominant_hz(samples: np.ndarray, rate: int) -> float:
    spectrum = np.abs(np.fft.rfft(samples * np.hanning(len(samples))))
    return float(np.argmax(spectrum) * rate / len(samples))


FORMATS = [  # file name, encoder, sample rate, channels, encoder options
    ("pcm16_16k.wav", "pcm_s16le", 16000, 1, None),
    ("pcm16_8k.wav", "pcm_s16le", 8000, 1, None),
    ("pcm24_48k_stereo.wav", "pcm_s24le", 48000, 2, None),
    ("float_22k.wav", "pcm_f32le", 22050, 1, None),
    ("stereo.flac", "flac", 44100, 2, None),
    ("stereo.mp3", "libmp3lame", 44100, 2, None),
    ("mono_24k.mp3", "libmp3lame", 24000, 1, None),
    ("stereo.ogg", "vorbis", 44100, 2, {"strict": "experimental"}),  # FFmpeg's own Vorbis encoder
    ("mono.opus", "libopus", 48000, 1, None),
    ("stereo_32k.m4a", "aac", 32000, 2, None),
]


@pytest.mark.parametrize("name, codec, rate, channels, options", FORMATS, ids=[f[0] for f in FORMATS])
def test_every_format_loads_as_the_same_tone(tmp_path, name, codec, rate, channels, options):
    path = write_tone(tmp_path / name, codec, rate, channels, options=options)

    samples = audio.load(path)

    assert samples.dtype == np.float32 and samples.ndim == 1
    assert abs(len(samples) / audio.ANALYSIS_RATE - SECONDS) <= TOLERANCE
    assert 0.8 * AMPLITUDE < np.abs(samples).max() < 1.3 * AMPLITUDE  # lossy codecs overshoot a little
    assert abs(dominant_hz(samples, audio.ANALYSIS_RATE) - TONE_HZ) < 5  # resampled, not sped up
    info = audio.probe(path)
    assert (info.sample_rate, info.channels) == (rate, channels)
    assert abs(info.duration - SECONDS) <= TOLERANCE


def test_stereo_is_averaged_to_mono(tmp_path):
    path = write_tone(tmp_path / "left_only.wav", "pcm_s16le", 44100, 2, right=np.zeros_like)

    samples = audio.load(path)

    assert samples.ndim == 1
    assert np.abs(samples).max() == pytest.approx(AMPLITUDE / 2, rel=0.05)


def test_load_resamples_to_the_asked_rate(tmp_path):
    path = write_tone(tmp_path / "tone.wav", "pcm_s16le", 44100, 1)

    samples = audio.load(path, sample_rate=8000)

    assert len(samples) == pytest.approx(SECONDS * 8000, abs=1)
    assert abs(dominant_hz(samples, 8000) - TONE_HZ) < 5


def test_float_wav_past_full_scale_is_clipped(tmp_path):
    path = write_tone(tmp_path / "hot.wav", "pcm_f32le", 16000, 1, amplitude=2.0)

    samples = audio.load(path)

    assert samples.max() == 1.0 and samples.min() == -1.0


def test_iter_resampled_streams_frames_for_the_encoder(tmp_path):
    path = write_tone(tmp_path / "tone.flac", "flac", 22050, 1)

    frames = list(audio.iter_resampled(path, 48000, "stereo"))

    assert {(f.sample_rate, f.layout.name, f.format.name) for f in frames} == {(48000, "stereo", "fltp")}
    assert sum(f.samples for f in frames) == pytest.approx(SECONDS * 48000, abs=48)


def test_soundtrack_of_a_real_video_loads():
    video = shared("video", "face_1.mp4")

    samples = audio.load(video)

    assert len(samples) / audio.ANALYSIS_RATE == pytest.approx(audio.probe(video).duration, abs=TOLERANCE)
    audio.check_audible(samples, video)


def _random_bytes(path):
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes())


def _truncated_header(path):
    write_tone(path, "pcm_s16le", 16000, 1)
    path.write_bytes(path.read_bytes()[:30])


def _png(path):
    cv2.imwrite(str(path.with_suffix(".png")), np.zeros((8, 8, 3), np.uint8))
    path.with_suffix(".png").rename(path)


def _zero_length_wav(path):
    with wave.open(str(path), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(16000)


def _empty_file(path):
    path.write_bytes(b"")


BAD_FILES = [  # how the file is spoiled, what the message must say
    (_random_bytes, "cannot read"),
    (_truncated_header, "cannot read"),
    (_png, "no audio stream"),
    (_zero_length_wav, "no audio samples"),
    (_empty_file, "cannot read"),
]


@pytest.mark.parametrize("spoil, message", BAD_FILES, ids=[f[0].__name__.strip("_") for f in BAD_FILES])
def test_bad_files_raise_puppet_error(tmp_path, spoil, message):
    path = tmp_path / "speech.wav"
    spoil(path)

    with pytest.raises(PuppetError, match=message):
        audio.probe(path)
    with pytest.raises(PuppetError, match=message):
        audio.load(path)


def test_missing_file_and_folder_raise_puppet_error(tmp_path):
    with pytest.raises(PuppetError, match="not found"):
        audio.load(tmp_path / "nowhere.wav")
    with pytest.raises(PuppetError, match="folder"):
        audio.probe(tmp_path)
    with pytest.raises(PuppetError, match="not found"):
        audio.iter_resampled(tmp_path / "nowhere.wav", 48000)


def test_corruption_mid_file_raises_puppet_error(tmp_path):
    path = write_tone(tmp_path / "glitch.mp3", "libmp3lame", 44100, 2, seconds=2.0)
    data = bytearray(path.read_bytes())
    third = len(data) // 3
    data[third : 2 * third] = bytes(third)
    path.write_bytes(bytes(data))

    with pytest.raises(PuppetError, match="cannot decode"):
        audio.load(path)


def test_silence_is_not_audible(tmp_path):
    silent = audio.load(write_tone(tmp_path / "silent.wav", "pcm_s16le", 16000, 1, amplitude=0.0))
    with pytest.raises(PuppetError, match="silent"):
        audio.check_audible(silent, "silent.wav")
    with pytest.raises(PuppetError, match="silent"):
        audio.check_audible(np.full(16000, 10 ** (-90 / 20), np.float32), "speech.wav")
    quiet = audio.load(write_tone(tmp_path / "quiet.wav", "pcm_s16le", 16000, 1, amplitude=10 ** (-60 / 20)))
    audio.check_audible(quiet, "quiet.wav")
