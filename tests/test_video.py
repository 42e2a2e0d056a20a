import av
import numpy as np
import pytest

from puppet import audio, track, video
from puppet.renderer import Background


def test_export_matches_the_audio_and_carries_it(tmp_path, demo, demo_speech):
    out = video.render(demo, demo_speech, tmp_path / "demo.mp4", video.VideoOptions(size=(256, 256)), progress=False)
    duration = audio.probe(demo_speech).duration
    with av.open(str(out)) as container:
        kinds = sorted(s.type for s in container.streams)
        frames = sum(1 for _ in container.decode(video=0))
        stream = container.streams.audio[0]
        audio_seconds = float(stream.duration * stream.time_base)
    assert kinds == ["audio", "video"]
    assert abs(frames / 25 - duration) <= 1 / 25
    assert abs(audio_seconds - duration) <= 1 / 25


def test_demo_motion_never_folds_the_mesh(demo, demo_speech):
    motion = video.make_motion(demo, demo_speech, video.VideoOptions())
    positions = demo.rig.animate(motion)
    assert not demo.rig._folded(positions).any()
    mouth_gap = positions[:, 66, 1] - positions[:, 62, 1]
    assert mouth_gap.max() > 0.15 * (positions[0, 45, 0] - positions[0, 36, 0])  # it talks
    assert mouth_gap.min() < 0.5  # and closes


def test_png_frames_keep_alpha_and_count(tmp_path, demo, demo_speech):
    out = video.render(demo, demo_speech, tmp_path / "frames", video.VideoOptions(size=(64, 64), fps=10), progress=False)
    frames = sorted(out.glob("*.png"))
    assert len(frames) == int(np.ceil(audio.probe(demo_speech).duration * 10 - 1e-6))
    import cv2

    first = cv2.imread(str(frames[0]), cv2.IMREAD_UNCHANGED)
    assert first.shape == (64, 64, 4) and first[0, 0, 3] == 0 and first[32, 32, 3] == 255


def test_track_written_with_landmarks_out_drives_the_same_video(tmp_path, demo, demo_speech):
    options = video.VideoOptions(size=(96, 96), background=Background((1, 1, 1, 1)))
    first = video.render(demo, demo_speech, tmp_path / "a", options, landmarks_out=tmp_path / "motion.npz", progress=False)
    landmarks, fps = track.read(tmp_path / "motion.npz")
    assert landmarks.shape == (len(list(first.glob("*.png"))), 68, 3) and fps == 25
    from dataclasses import replace

    second = video.render(demo, demo_speech, tmp_path / "b", replace(options, motion=str(tmp_path / "motion.npz")), progress=False)
    import cv2

    for a, b in list(zip(sorted(first.glob("*.png")), sorted(second.glob("*.png"))))[::20]:
        assert np.abs(cv2.imread(str(a)).astype(int) - cv2.imread(str(b))).max() <= 2


def test_output_size_defaults_to_the_portrait_capped_and_even():
    assert video.output_size((512, 512)) == (512, 512)
    assert video.output_size((3001, 1001)) == (1080, 360)
    width, height = video.output_size((641, 481))
    assert width % 2 == height % 2 == 0 and abs(width - 641) <= 1 and abs(height - 481) <= 1


def test_a_track_of_another_face_is_refused(tmp_path, demo, demo_speech):
    from dataclasses import replace

    from puppet.errors import PuppetError

    landmarks, _ = np.repeat(demo.rig.landmarks[None] * 0.5 + 40, 10, axis=0), 25
    track.write(tmp_path / "other.npz", landmarks.astype(np.float32), 25)
    options = replace(video.VideoOptions(size=(64, 64)), motion=str(tmp_path / "other.npz"))
    with pytest.raises(PuppetError, match="another face"):
        video.render(demo, demo_speech, tmp_path / "x.mp4", options, progress=False)
    assert not (tmp_path / "x.mp4").exists()


def test_an_expression_is_held_through_the_clip(demo, demo_speech):
    from dataclasses import replace

    from puppet.expression import expression_offsets

    neutral = video.VideoOptions(motion="loudness")
    plain = video.make_motion(demo, demo_speech, neutral)
    happy = video.make_motion(demo, demo_speech, replace(neutral, expression="happy"))
    np.testing.assert_allclose(happy.offsets - plain.offsets, np.broadcast_to(expression_offsets(demo.rig.landmarks, "happy"), plain.offsets.shape), atol=1e-4)
