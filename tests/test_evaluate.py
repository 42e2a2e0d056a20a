import numpy as np
import pytest
from conftest import shared

from puppet import evaluate
from puppet.visemes import canonical_rest


def moving_face(frames=40, seed=0):
    """(T, 68, 3) canonical faces whose jaw opens and closes."""
    rest = canonical_rest()
    opening = 0.3 * np.sin(np.linspace(0, 4 * np.pi, frames)) ** 2
    faces = np.repeat(rest[None], frames, axis=0)
    faces[:, 55:60, 1] += opening[:, None]
    faces[:, 65:68, 1] += opening[:, None]
    return faces + np.random.default_rng(seed).normal(0, 0.002, faces.shape).astype(np.float32)


def test_identical_motion_scores_zero_and_perfect_correlation():
    faces = moving_face()
    scores = evaluate.metrics(faces, faces)
    assert all(scores[k] == pytest.approx(0, abs=1e-9) for k in ["D-LL", "D-VL", "D-A", "D-L", "D-V"])
    assert scores["lip_corr"] == pytest.approx(1.0)


def test_a_still_face_scores_worse_than_the_motion_itself():
    faces = moving_face()
    still = np.repeat(canonical_rest()[None], len(faces), axis=0)
    assert evaluate.metrics(still, faces)["D-A"] > 20
    assert evaluate.metrics(moving_face(seed=1), faces)["D-A"] < 5


def test_alignment_removes_head_pose():
    faces = moving_face()[..., :2]
    angle = np.radians(20)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    seen = faces @ turn.T * 90 + [300, 200]  # the same motion, turned, scaled and shifted
    assert np.abs(evaluate.align_to(seen, canonical_rest()) - faces).max() < 0.01


def test_the_rest_face_has_closed_lips():
    """Half the frames talk (lips apart), half rest: the rest face is the resting one, not the median."""
    rest = canonical_rest()[:, :2]
    talking = rest.copy()
    talking[65:68, 1] += 0.3  # the lower inner lip drops
    frames = np.stack([talking] * 60 + [rest] * 40)
    np.testing.assert_allclose(evaluate.rest_face(frames), rest)


def test_real_video_is_tracked_and_baselines_are_scored(tmp_path):
    video = shared("video", "face_1.mp4")
    canonical = canonical_rest()
    scores = evaluate.score_video(video, evaluate.baselines(canonical), canonical, cache=tmp_path)
    assert abs(scores["static"]["lip_corr"]) < 1e-3 and scores["loudness"]["lip_corr"] > 0.2
    assert (tmp_path / "face_1.npz").is_file()


def test_lip_opening_plot_is_drawn(tmp_path):
    """A picture with one row per moving source; the static face has no row."""
    import cv2

    real = moving_face(50)[..., :2]
    predicted = {"learned": moving_face(50, seed=1)[..., :2], "static": np.repeat(real[:1], 50, axis=0)}
    evaluate.plot_openings("clip.mp4", real, predicted, {"learned": 0.5, "static": 0.0}, 25.0, tmp_path / "clip.png")
    picture = cv2.imread(str(tmp_path / "clip.png"))
    assert picture.shape == (40 + 150, 1200, 3) and (picture < 128).any()


def test_training_labels_are_scored_against_festivals_own_phone_times():
    pytest.importorskip("pocketsphinx")
    from puppet import corpus

    if not (corpus.engine_available("festival") and corpus.festival_has("kal_diphone")):
        pytest.skip("festival's kal_diphone voice is not installed")
    scores = evaluate.score_labels(3, voices=("kal_diphone",))
    aligned, late = scores["motion"]["aligned"], scores["motion"]["1 frame late"]
    assert scores["boundaries"]["median_ms"] <= 20 and scores["boundaries"]["within_20ms"] > 0.6
    assert aligned["D-A"] < 6 and aligned["lip_corr"] > 0.9
    assert 0 < late["D-LL"] and late["lip_corr"] < 1


def test_sounds_with_nobody_speaking_are_scored_by_how_far_the_mouth_opens(tmp_path, monkeypatch):
    """Music and typing made up from seeds training never drew: the learned sources (and --recognise) keep the lips near
    rest where the loudness baseline opens them; a folder without audio is refused."""
    import wave

    from puppet import lipsync, nonspeech
    from puppet.errors import PuppetError

    if not lipsync.has_model():
        pytest.skip("no trained model in assets/models")
    monkeypatch.setattr(nonspeech, "soundfont", lambda: None)  # the same sounds with or without fluidsynth
    for name, clip in {"music": nonspeech.music(64000, np.random.default_rng(31)),
                       "typing": nonspeech.knocks(64000, np.random.default_rng(32))}.items():
        with wave.open(str(tmp_path / f"{name}.wav"), "wb") as f:
            f.setnchannels(1), f.setsampwidth(2), f.setframerate(16000)
            f.writeframes((nonspeech._normalised(clip) * 32767).astype("<i2").tobytes())
    (tmp_path / "notes.txt").write_text("not audio")
    scores = evaluate.score_sounds(tmp_path)
    rest = scores["learned"]["rest_gap"]
    assert scores["static"]["mean_gap"] == pytest.approx(rest) and scores["static"]["worst_gap"] == pytest.approx(rest)
    for name in ("learned", "learned-live", "recognised"):  # words the recogniser hears in music move nothing
        assert scores[name]["worst_gap"] < rest + 0.02
    assert scores["loudness"]["mean_gap"] > rest + 0.05
    with pytest.raises(PuppetError, match="no audio files"):
        evaluate.score_sounds(tmp_path / "nothing")
