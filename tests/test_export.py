"""Export: videos play with their sound in sync, PNG folders keep alpha, and nothing half-written is left."""
import math

import av
import cv2
import numpy as np
import pytest

from puppet import audio, export
from puppet.errors import PuppetError

SIZE = (96, 64)  # (W, H) pixels, even for H.264
FPS = 25
SPEECH_SECONDS = 1.03  # not a whole number of frames, so the last frame is a partial one
COLOUR = (200, 60, 30)  # RGB of the test frames


def write_speech(path, codec="pcm_s16le", seconds=SPEECH_SECONDS, rate=44100, layout="stereo"):
    """A recording of `seconds`: a tone at -10 dBFS, loud enough to hear."""
    t = np.arange(round(seconds * rate)) / rate
    tone = (0.3 * np.sin(2 * np.pi * 220 * t)).astype(np.float32)
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=rate, layout=layout)
        planes = np.stack([tone] * stream.channels)
        frame = av.AudioFrame.from_ndarray(planes, format="fltp", layout=layout)
        frame.sample_rate, frame.pts = rate, 0
        for packet in [*stream.encode(frame), *stream.encode(None)]:
            container.mux(packet)
    return path


@pytest.fixture(scope="module")
def speech(tmp_path_factory):
    return write_speech(tmp_path_factory.mktemp("audio") / "speech.wav")


def solid(colour=COLOUR) -> np.ndarray:
    """(H, W, 4) uint8 RGBA frame of one opaque colour."""
    frame = np.empty((SIZE[1], SIZE[0], 4), np.uint8)
    frame[:] = (*colour, 255)
    return frame


def leftovers(folder) -> list[str]:
    """Names in `folder` other than inputs: partial outputs would show up here."""
    return sorted(p.name for p in folder.iterdir() if p.name != "speech.wav")


@pytest.mark.parametrize("suffix", [".mp4", ".mov", ".mkv"])
def test_video_has_the_speech_in_sync(tmp_path, speech, suffix):
    frames = math.ceil(SPEECH_SECONDS * FPS)
    out = tmp_path / f"talk{suffix}"

    with export.open_output(out, SIZE, FPS, audio_path=speech) as writer:
        for _ in range(frames):
            writer.send(solid())

    with av.open(str(out)) as container:
        assert len(container.streams.video) == 1 and len(container.streams.audio) == 1
        assert container.streams.audio[0].rate == 44100  # a common rate is kept, not resampled
        assert abs(container.duration / av.time_base - audio.probe(speech).duration) <= 1 / FPS
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(decoded) == frames
    assert decoded[0].shape == (SIZE[1], SIZE[0], 3)
    assert np.abs(decoded[frames // 2][SIZE[1] // 2, SIZE[0] // 2].astype(int) - COLOUR).max() <= 6
    assert leftovers(tmp_path) == [out.name]


def test_video_audio_is_complete_and_audible(tmp_path, speech):
    out = tmp_path / "talk.mp4"

    with export.VideoWriter(out, SIZE, FPS, audio_path=speech) as writer:
        for _ in range(math.ceil(SPEECH_SECONDS * FPS)):
            writer.send(solid())

    sound = audio.load(out)
    assert len(sound) / audio.ANALYSIS_RATE == pytest.approx(SPEECH_SECONDS, abs=1 / FPS)
    assert np.abs(sound).max() == pytest.approx(0.3, rel=0.15)


def test_uncommon_audio_rates_are_resampled_for_aac(tmp_path):
    phone = write_speech(tmp_path / "speech.wav", rate=8000, layout="mono")
    out = tmp_path / "talk.mp4"

    with export.open_output(out, SIZE, FPS, audio_path=phone) as writer:
        for _ in range(math.ceil(SPEECH_SECONDS * FPS)):
            writer.send(solid())

    with av.open(str(out)) as container:
        sound = container.streams.audio[0]
        assert (sound.rate, sound.channels) == (export.AAC_FALLBACK_RATE, 1)
        assert abs(container.duration / av.time_base - SPEECH_SECONDS) <= 1 / FPS


def test_video_without_audio_has_no_audio_stream(tmp_path):
    out = tmp_path / "silent.mp4"

    with export.open_output(out, SIZE, FPS) as writer:
        for _ in range(10):
            writer.send(solid())

    with av.open(str(out)) as container:
        assert [s.type for s in container.streams] == ["video"]
        assert container.duration / av.time_base == pytest.approx(10 / FPS, abs=1 / FPS)


def test_png_folder_keeps_alpha_exactly(tmp_path):
    out = tmp_path / "frames"
    rng = np.random.default_rng(0)
    sent = [rng.integers(0, 256, (SIZE[1], SIZE[0], 4), dtype=np.uint8) for _ in range(3)]

    with export.open_output(out, SIZE, FPS) as writer:
        for frame in sent:
            writer.send(frame)

    assert sorted(p.name for p in out.iterdir()) == [f"frame_{i:06d}.png" for i in range(3)]
    for i, frame in enumerate(sent):
        bgra = cv2.imread(str(out / f"frame_{i:06d}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(cv2.cvtColor(bgra, cv2.COLOR_BGRA2RGBA), frame)
    assert leftovers(tmp_path) == ["frames"]


@pytest.mark.parametrize("name", ["talk.mp4", "frames"])
@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_exception_inside_with_leaves_nothing(tmp_path, speech, name, error):
    with pytest.raises(error), export.open_output(tmp_path / name, SIZE, FPS, audio_path=speech) as writer:
        writer.send(solid())
        writer.send(solid())
        raise error()

    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("name", ["talk.mp4", "frames"])
def test_existing_output_is_kept_without_force(tmp_path, name):
    out = tmp_path / name
    old = out if out.suffix else out / "frame_000000.png"
    old.parent.mkdir(exist_ok=True)
    old.write_bytes(b"old output")

    with pytest.raises(PuppetError, match="exists; use --force"):
        export.check_output(out, force=False)
    with pytest.raises(PuppetError, match="exists; use --force"):
        export.open_output(out, SIZE, FPS)

    assert leftovers(tmp_path) == [name]
    assert old.read_bytes() == b"old output"


@pytest.mark.parametrize("name", ["talk.mp4", "frames"])
def test_force_replaces_existing_output(tmp_path, name):
    out = tmp_path / name
    with export.open_output(out, SIZE, FPS) as writer:
        for _ in range(3):
            writer.send(solid((0, 0, 0)))

    with export.open_output(out, SIZE, FPS, force=True) as writer:
        writer.send(solid())

    assert leftovers(tmp_path) == [name]
    if out.suffix:
        with av.open(str(out)) as container:
            assert container.streams.video[0].frames == 1
    else:
        assert [p.name for p in out.iterdir()] == ["frame_000000.png"]


def test_force_never_replaces_a_folder_of_other_files(tmp_path):
    precious = tmp_path / "photos"
    precious.mkdir()
    (precious / "holiday.jpg").write_bytes(b"memories")
    folder_named_like_a_video = tmp_path / "clip.mp4"
    folder_named_like_a_video.mkdir()

    with pytest.raises(PuppetError, match="refusing"):
        export.check_output(precious, force=True)
    with pytest.raises(PuppetError, match="is a folder"):
        export.check_output(folder_named_like_a_video, force=True)
    assert (precious / "holiday.jpg").read_bytes() == b"memories"


def test_output_appearing_during_render_is_not_overwritten(tmp_path):
    out = tmp_path / "talk.mp4"
    writer = export.open_output(out, SIZE, FPS)
    writer.send(solid())
    out.write_bytes(b"someone else's")

    with pytest.raises(PuppetError, match="exists"):
        writer.close()

    assert out.read_bytes() == b"someone else's"
    assert leftovers(tmp_path) == ["talk.mp4"]


@pytest.mark.parametrize(
    "path, message",
    [
        ("missing/talk.mp4", "output folder does not exist"),
        ("talk.avi", "unsupported output type"),
        ("talk.gif", "unsupported output type"),
    ],
)
def test_bad_output_paths_are_refused(tmp_path, path, message):
    with pytest.raises(PuppetError, match=message):
        export.check_output(tmp_path / path, force=False)
    with pytest.raises(PuppetError, match=message):
        export.open_output(tmp_path / path, SIZE, FPS)


def test_bad_video_settings_are_refused_before_writing(tmp_path):
    not_audio = tmp_path / "face.png"
    cv2.imwrite(str(not_audio), np.zeros((8, 8, 3), np.uint8))

    with pytest.raises(PuppetError, match="even"):
        export.open_output(tmp_path / "odd.mp4", (95, 64), FPS)
    with pytest.raises(PuppetError, match="preset"):
        export.open_output(tmp_path / "slow.mp4", SIZE, FPS, preset="glacial")
    with pytest.raises(PuppetError, match="no audio stream"):
        export.open_output(tmp_path / "mute.mp4", SIZE, FPS, audio_path=not_audio)

    assert sorted(p.name for p in tmp_path.iterdir()) == ["face.png"]


def test_encoder_error_reaches_the_caller_and_leaves_nothing(tmp_path):
    glitch = write_speech(tmp_path / "speech.mp3", "libmp3lame", seconds=4.0)
    data = bytearray(glitch.read_bytes())
    third = len(data) // 3
    data[third : 2 * third] = bytes(third)  # decodes at first, fails a second or so in
    glitch.write_bytes(bytes(data))

    writer = export.open_output(tmp_path / "talk.mp4", SIZE, FPS, audio_path=glitch)
    with pytest.raises(PuppetError, match="cannot decode"), writer:
        for _ in range(4 * FPS):
            writer.send(solid())

    assert sorted(p.name for p in tmp_path.iterdir()) == ["speech.mp3"]


def test_wrong_frame_shape_is_a_caller_bug(tmp_path):
    with export.open_output(tmp_path / "talk.mp4", SIZE, FPS) as writer:
        with pytest.raises(ValueError, match="RGBA"):
            writer.send(solid()[..., :3])
        writer.send(solid())


@pytest.mark.parametrize("name", ["talk.mp4", "frames"])
def test_no_frames_is_an_error_not_an_empty_output(tmp_path, name):
    with pytest.raises(PuppetError, match="no frames"), export.open_output(tmp_path / name, SIZE, FPS):
        pass

    assert list(tmp_path.iterdir()) == []
