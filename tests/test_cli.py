"""The `puppet` command as a user meets it: bad input ends in one line and exit 2, nothing left behind."""
import sys
import wave

import cv2
import numpy as np
import pytest

from puppet import bundle
from puppet.cli import main


def write_wav(path, samples, rate=16000):
    with wave.open(str(path), "wb") as out:
        out.setnchannels(1)
        out.setsampwidth(2)
        out.setframerate(rate)
        out.writeframes((np.clip(samples, -1, 1) * 32767).astype("<i2").tobytes())
    return path


@pytest.fixture
def files(tmp_path, demo):
    """A scratch folder with a good portrait, its landmarks and a short speech clip."""
    image, landmarks, speech = bundle.demo_files()
    t = np.arange(16000) / 16000
    voiced = 0.3 * np.sin(2 * np.pi * 140 * t) * (np.sin(2 * np.pi * 3 * t) > 0)
    return {
        "image": image,
        "landmarks": landmarks,
        "speech": write_wav(tmp_path / "speech.wav", voiced),
        "dir": tmp_path,
    }


def put(path, data: bytes):
    path.write_bytes(data)
    return path


def fails(capsys, args, message):
    """Run the CLI expecting a one-line error containing `message`."""
    code = main([str(a) for a in args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert message in err, err
    return err


def only(folder, *names):
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)


def test_render_from_image_and_landmarks(files, capsys):
    out = files["dir"] / "talk.mp4"
    assert main(["render", str(files["image"]), str(files["speech"]), "--landmarks", str(files["landmarks"]), "-o", str(out), "-q", "--size", "128"]) == 0
    assert out.stat().st_size > 1000
    only(files["dir"], "speech.wav", "talk.mp4")


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "nope.png", "image not found"),
        (lambda d: put(d / "text.png", b"hello"), "cannot read"),
        (lambda d: cv2.imwrite(str(d / "huge.png"), np.zeros((10000, 10000), np.uint8)) and d / "huge.png", "scale it down"),
    ],
)
def test_bad_images(files, capsys, make, message):
    fails(capsys, ["render", make(files["dir"]), files["speech"], "--landmarks", files["landmarks"], "-o", files["dir"] / "out.mp4"], message)
    assert not (files["dir"] / "out.mp4").exists()


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "nope.wav", "not found"),
        (lambda d: put(d / "junk.wav", np.random.default_rng(0).bytes(5000)), "junk.wav"),
        (lambda d: write_wav(d / "empty.wav", np.zeros(0)), "empty.wav"),
        (lambda d: write_wav(d / "silent.wav", np.zeros(16000)), "silent"),
    ],
)
def test_bad_audio(files, capsys, make, message):
    path = make(files["dir"])
    fails(capsys, ["render", files["image"], path, "--landmarks", files["landmarks"], "-o", files["dir"] / "out.mp4"], message)
    assert not (files["dir"] / "out.mp4").exists()
    assert not list(files["dir"].glob(".*"))


def test_no_face_tells_how_to_rig_by_hand(files, capsys):
    blank = files["dir"] / "blank.png"
    cv2.imwrite(str(blank), np.full((200, 200, 3), 200, np.uint8))
    fails(capsys, ["render", blank, files["speech"], "-o", files["dir"] / "out.mp4"], "puppet rig")


@pytest.mark.parametrize("shift, rows, message", [(0, 2, "68 rows"), (5000, 68, "outside")], ids=["two rows", "off the image"])
def test_bad_landmarks(files, capsys, demo, shift, rows, message):
    bad = files["dir"] / "bad.txt"
    np.savetxt(bad, demo.rig.landmarks[:rows, :2] + shift)
    fails(capsys, ["render", files["image"], files["speech"], "--landmarks", bad, "-o", files["dir"] / "out.mp4"], message)


def test_output_in_a_missing_folder(files, capsys):
    fails(capsys, ["render", "--demo", "-o", files["dir"] / "missing" / "out.mp4"], "does not exist")


def test_existing_output_is_kept_without_force(files, capsys):
    out = files["dir"] / "out.mp4"
    out.write_bytes(b"precious")
    fails(capsys, ["render", "--demo", "-o", out], "--force")
    assert out.read_bytes() == b"precious"


def test_unsupported_output_suffix(files, capsys):
    fails(capsys, ["render", "--demo", "-o", files["dir"] / "out.gif"], "")


def test_rig_with_points_then_render_the_bundle(files, capsys, demo):
    from puppet.template import control_points

    points = [f"{x:.1f},{y:.1f}" for x, y in control_points(demo.rig.landmarks[:, :2])]
    folder = files["dir"] / "pip.puppet"
    assert main(["rig", str(files["image"]), "--points", *points, "-o", str(folder)]) == 0
    assert (folder / "preview.png").is_file()
    out = files["dir"] / "frames"
    assert main(["render", str(folder), str(files["speech"]), "-o", str(out), "-q", "--size", "96"]) == 0
    frames = sorted(out.glob("*.png"))
    assert len(frames) == 25
    assert cv2.imread(str(frames[0]), cv2.IMREAD_UNCHANGED).shape == (96, 96, 4)


def test_bad_points(files, capsys):
    fails(capsys, ["rig", files["image"], "--points", "1,2", "3,4", "5,6", "7,8", "nine"], "--points")


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "render" in out and "rig" in out and "bench" in out and "live" in out


@pytest.mark.skipif(not __import__("puppet.lipsync").lipsync.has_model(), reason="no trained model")
def test_predict_writes_a_track_that_render_plays(files, capsys, demo, demo_speech):
    from puppet import track

    face = files["dir"] / "face.txt"
    np.savetxt(face, demo.rig.landmarks[:, :2])
    out = files["dir"] / "motion.npz"
    assert main(["predict", str(demo_speech), "--face", str(face), "-o", str(out)]) == 0
    landmarks, fps = track.read(out)
    assert fps == 25 and landmarks.shape[1:] == (68, 3)
    assert np.abs(landmarks[0, :, :2] - demo.rig.landmarks[:, :2]).max() < 0.3 * 92  # the face's own landmarks, in motion
    video = files["dir"] / "from_track.mp4"
    assert main(["render", str(files["image"]), str(demo_speech), "--landmarks", str(files["landmarks"]), "--motion", str(out), "-o", str(video), "-q", "--size", "96"]) == 0


def test_live_help_names_the_keys_to_obs_and_the_devices(capsys):
    with pytest.raises(SystemExit):
        main(["live", "--help"])
    out = capsys.readouterr().out
    for words in ("--virtual-camera", "--list-devices", "--audio", "--stats", "OBS"):
        assert words in out, words


def test_eval_keeps_existing_results(files, capsys):
    scores = put(files["dir"] / "scores.json", b"{}")
    fails(capsys, ["eval", "--videos", files["dir"], "--json", scores], "use --force")
    plots = files["dir"] / "plots"
    plots.mkdir()
    put(plots / "old.png", b"x")
    fails(capsys, ["eval", "--videos", files["dir"], "--plots", plots], "use --force")
    fails(capsys, ["eval", "--videos", files["dir"]], "no .mp4/.mov/.mkv videos")
    fails(capsys, ["eval", "--videos", files["dir"], "--plots", scores / "plots"], "cannot make the --plots folder")
    fails(capsys, ["eval", "--labels", "0"], "1 or more")
    fails(capsys, ["eval"], "--labels N")
    assert scores.read_bytes() == b"{}" and (plots / "old.png").read_bytes() == b"x"


def test_train_without_onnx_stops_before_building_anything(files, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnx", None)  # as if the train extra were installed without it
    corpus = files["dir"] / "corpus"
    fails(capsys, ["train", "--corpus", corpus, "--out", files["dir"] / "runs"], "onnx is missing")
    assert not corpus.exists()


def test_a_bad_option_is_one_line(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["render", "--demo", "-o", "x.mp4", "--fps", "fast"])
    err = capsys.readouterr().err.strip()
    assert exit_.value.code == 2 and len(err.splitlines()) == 1 and "--fps" in err and "--help" in err


def test_a_transcript_of_other_words_is_warned_of_in_one_line(files, capsys, demo_speech):
    text = demo_speech.with_suffix(".txt").read_text()
    other = files["dir"] / "other.txt"
    other.write_text(text.replace(text.split(".")[1], " The quick brown fox jumps over the lazy dog", 1))
    out = files["dir"] / "motion.npz"
    assert main(["predict", str(demo_speech), "--transcript", str(other), "-o", str(out)]) == 0
    aligning, warning = capsys.readouterr().err.strip().splitlines()
    assert aligning.startswith("aligning the transcript")
    assert warning.startswith("puppet: warning: the transcript does not fit the audio at 0:0") and out.is_file()


def test_bad_transcripts(files, capsys, demo_speech):
    out = files["dir"] / "out.mp4"
    fails(capsys, ["render", "--demo", "--transcript", files["dir"] / "missing.txt", "-o", out], "cannot read the transcript")
    text = demo_speech.with_suffix(".txt")
    fails(capsys, ["render", "--demo", "--motion", "loudness", "--transcript", text, "-o", out], "learned motion only")
    assert not out.exists()


def test_recognising_the_words_needs_the_learned_motion_and_no_transcript(files, capsys, demo_speech):
    out, track = files["dir"] / "out.mp4", files["dir"] / "motion.npz"
    text = demo_speech.with_suffix(".txt")
    fails(capsys, ["render", "--demo", "--motion", "loudness", "--recognise", "-o", out], "learned motion only")
    fails(capsys, ["render", "--demo", "--transcript", text, "--recognise", "-o", out], "not both")
    fails(capsys, ["predict", demo_speech, "--transcript", text, "--recognise", "-o", track], "not both")
    assert not out.exists() and not track.exists()
    out.write_bytes(b"precious")  # refused in one line, before any "recognising…" or "aligning…" notice
    fails(capsys, ["render", "--demo", "--recognise", "-o", out], "--force")
    fails(capsys, ["render", "--demo", "--transcript", text, "-o", out], "--force")
    assert out.read_bytes() == b"precious"
    assert main(["predict", str(demo_speech), "--recognise", "-o", str(track)]) == 0
    assert capsys.readouterr().err.startswith("recognising the words") and track.is_file()
