import numpy as np
import pytest
from conftest import drawn_face

from puppet import track
from puppet.errors import PuppetError
from puppet.motion import Motion
from puppet.pose import posed_landmarks

FPS = 30.0




REST = drawn_face(centre=(300.0, 280.0), iod=120.0, tilt_degrees=-12.0)


def random_motion(frames, seed, degrees=15.0, offset_pixels=3.0):
    """Poses within ±degrees on every axis, shifts within ±40 px, offsets of about offset_pixels."""
    rng = np.random.default_rng(seed)
    return Motion(
        offsets=rng.normal(0.0, offset_pixels, (frames, 68, 3)).astype(np.float32),
        rotation=np.radians(rng.uniform(-degrees, degrees, (frames, 3))).astype(np.float32),
        translation=rng.uniform(-40.0, 40.0, (frames, 2)).astype(np.float32),
        fps=FPS,
    )


def test_write_then_read_gives_the_track_back(tmp_path):
    landmarks = posed_landmarks(REST, random_motion(12, seed=0))
    track.write(tmp_path / "take.npz", landmarks, FPS)
    read, fps = track.read(tmp_path / "take.npz")
    assert fps == FPS and read.dtype == np.float32
    np.testing.assert_array_equal(read, landmarks)
    assert [p.name for p in tmp_path.iterdir()] == ["take.npz"]


def test_write_keeps_the_exact_path(tmp_path):
    track.write(tmp_path / "take.track", posed_landmarks(REST, Motion.still(2, FPS)), 24)
    assert track.read(tmp_path / "take.track")[1] == 24.0


def bad_files(folder):
    """{description: path} of files that are not usable tracks."""
    good = posed_landmarks(REST, Motion.still(3, FPS))
    files = {}

    def npz(name, **arrays):
        files[name] = folder / f"{name}.npz"
        with open(files[name], "wb") as file:
            np.savez(file, **arrays)

    files["missing"] = folder / "nowhere.npz"
    files["garbage"] = folder / "garbage.npz"
    files["garbage"].write_bytes(b"this is not a zip file at all")
    files["empty"] = folder / "empty.npz"
    files["empty"].write_bytes(b"")
    files["truncated"] = folder / "truncated.npz"
    npz("whole", landmarks=good, fps=FPS)
    files["truncated"].write_bytes(files["whole"].read_bytes()[:200])
    files["npy"] = folder / "bare.npz"
    with open(files["npy"], "wb") as file:
        np.save(file, good)
    npz("no_fps", landmarks=good)
    npz("no_landmarks", points=good, fps=FPS)
    npz("two_d", landmarks=good[..., :2], fps=FPS)
    npz("five_points", landmarks=good[:, :5], fps=FPS)
    npz("no_frames", landmarks=good[:0], fps=FPS)
    npz("nan", landmarks=np.where(np.arange(68)[:, None] == 7, np.nan, good), fps=FPS)
    npz("zero_fps", landmarks=good, fps=0.0)
    npz("negative_fps", landmarks=good, fps=-25.0)
    npz("fps_array", landmarks=good, fps=np.array([25.0, 30.0]))
    npz("text_fps", landmarks=good, fps="fast")
    npz("pickled", landmarks=np.array([good, "x"], dtype=object), fps=FPS)
    del files["whole"]
    return files


def test_unusable_files_raise_a_puppet_error_naming_the_file(tmp_path):
    for description, path in bad_files(tmp_path).items():
        with pytest.raises(PuppetError) as error:
            track.read(path)
        assert path.name in str(error.value), description


@pytest.mark.parametrize("landmarks, fps", [
    (np.zeros((3, 68, 2)), FPS), (np.zeros((0, 68, 3)), FPS), (np.full((2, 68, 3), np.inf), FPS),
    (np.zeros((2, 68, 3)), 0.0), (np.zeros((2, 68, 3)), float("nan")),
])
def test_writing_a_bad_track_raises(tmp_path, landmarks, fps):
    with pytest.raises(PuppetError):
        track.write(tmp_path / "bad.npz", landmarks, fps)


@pytest.mark.parametrize("seed", range(4))
def test_motion_from_track_reproduces_the_track(seed):
    landmarks = posed_landmarks(REST, random_motion(40, seed))
    motion = track.motion_from_track(landmarks, REST, FPS)
    assert len(motion) == 40 and motion.fps == FPS
    assert np.abs(posed_landmarks(REST, motion) - landmarks).max() < 0.01


def test_a_pure_head_pose_comes_back_as_that_pose_with_no_offsets():
    pose = random_motion(40, seed=5, offset_pixels=0.0)
    motion = track.motion_from_track(posed_landmarks(REST, pose), REST, FPS)
    np.testing.assert_allclose(motion.rotation, pose.rotation, atol=1e-4)
    np.testing.assert_allclose(motion.translation, pose.translation, atol=1e-2)
    assert np.abs(motion.offsets).max() < 1e-2


def test_expressions_stay_in_the_offsets_not_the_pose():
    pose = random_motion(20, seed=6, offset_pixels=0.0)
    mouth_open = np.zeros((20, 68, 3), np.float32)
    mouth_open[:, 55:60, 1] = mouth_open[:, 65:68, 1] = 30.0  # the lower lip drops, nothing stable moves
    talking = Motion(mouth_open, pose.rotation, pose.translation, FPS)
    motion = track.motion_from_track(posed_landmarks(REST, talking), REST, FPS)
    np.testing.assert_allclose(motion.rotation, pose.rotation, atol=1e-4)
    np.testing.assert_allclose(motion.offsets, mouth_open, atol=1e-2)


def test_a_flat_track_borrows_depth_from_the_rest_face():
    rolled = Motion.still(10, FPS)
    rolled.rotation[:, 2] = np.radians(np.linspace(-10.0, 10.0, 10))
    rolled.translation[:] = (5.0, -3.0)
    landmarks = posed_landmarks(REST, rolled)
    landmarks[..., 2] = 1.0  # what a 2-D detector's file carries
    motion = track.motion_from_track(landmarks, REST, FPS)
    np.testing.assert_allclose(motion.rotation, rolled.rotation, atol=1e-3)
    assert np.abs(posed_landmarks(REST, motion)[..., :2] - landmarks[..., :2]).max() < 0.01
