"""The shipped lip-sync model as a user meets it: it talks on speech, rests in silence, and takes any audio."""
import numpy as np
import pytest

from puppet import audio, lipsync
from puppet.errors import PuppetError, PuppetWarning
from puppet.evaluate import lip_opening
from puppet.features import motion_frame_count
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


def test_files_are_animated_with_both_networks_averaged(demo, demo_speech):
    samples = audio.load(demo_speech)
    both = lipsync.file_predictor()
    assert [p.lookahead for p in both.predictors] == [lipsync.shipped_predictor(kind).lookahead for kind in ("offline", "streaming")]
    rest, frames = demo.rig.landmarks, int(len(samples) / 16000 * FPS)
    default = lipsync.learned_motion(samples, rest, FPS, frames).offsets
    assert np.array_equal(default, lipsync.learned_motion(samples, rest, FPS, frames, both).offsets)
    assert not np.allclose(default, lipsync.learned_motion(samples, rest, FPS, frames, lipsync.shipped_predictor("offline")).offsets)


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


def test_pauses_are_found_from_the_recordings_own_levels():
    """Room tone 35 dB under the speech, 0.6 s long, is a pause; a 0.2 s gap between words is not."""
    rng = np.random.default_rng(0)
    t = np.arange(16000) / 16000
    speech = (0.3 * np.sin(2 * np.pi * 180 * t)).astype(np.float32)  # 1 s, frames 0–49
    room = rng.normal(0, 0.3 * 10 ** (-35 / 20), 16000).astype(np.float32)
    samples = np.concatenate([speech, room[:9600], speech, room[:3200], speech])  # pause: frames 50–79; gap: 130–139
    weights = lipsync.pause_weights(samples)
    assert weights.shape == (motion_frame_count(len(samples)),) and weights.dtype == np.float32
    assert np.all(weights[:50] == 1) and np.all(weights[80:] == 1)  # speech, and the short gap, untouched
    assert np.all(weights[55:75] == 0) and 0 < weights[52] < 1 and 0 < weights[77] < 1  # eased in and out
    assert np.all(lipsync.pause_weights(np.zeros(16000, np.float32)) == 1)  # nothing louder: no pause to find


def test_in_a_noisy_recording_pauses_are_found_near_its_noise_floor():
    """A fan 12 dB under the speech throughout (under 20 dB: the quiet rule alone finds no pause): the
    0.6 s of fan alone is a pause, the 0.2 s gap is not, and a steady noise with nothing louder has none."""
    rng = np.random.default_rng(0)
    t = np.arange(16000) / 16000
    speech = (0.3 * np.sin(2 * np.pi * 180 * t)).astype(np.float32)
    silent = np.zeros(9600, np.float32)
    clean = np.concatenate([speech, silent, speech, silent[:3200], speech])  # pause: frames 50–79; gap: 130–139
    fan = rng.normal(0, 0.3 / np.sqrt(2) * 10 ** (-12 / 20), len(clean)).astype(np.float32)
    weights = lipsync.pause_weights(clean + fan)
    assert np.all(weights[:50] == 1) and np.all(weights[80:] == 1)
    assert np.all(weights[55:75] == 0)
    assert np.all(lipsync.pause_weights(fan) == 1)


def test_the_mouth_rests_in_a_noisy_pause(demo, demo_speech):
    """A pause full of hiss (not digital silence) between two sentences: the lips come to rest."""
    speech = audio.load(demo_speech)
    hiss = np.random.default_rng(1).normal(0, np.abs(speech).max() * 10 ** (-40 / 20), 24000).astype(np.float32)
    gap = opening(demo, np.concatenate([speech, hiss, speech]))
    start = int(len(speech) / 16000 * FPS)
    assert np.abs(gap[start + 8 : start + int(1.5 * FPS) - 8]).max() < 0.002  # the network alone leaves ~0.008


def music_then_speech(speech: np.ndarray) -> np.ndarray:
    """3 s of made-up music (a seed training never drew; synthesised instruments, so the same with or
    without fluidsynth: patch nonspeech.soundfont), then the speech with the music going on 10 dB under it."""
    from puppet import nonspeech

    music = 0.5 * nonspeech._normalised(nonspeech.music(len(speech) + 48000, np.random.default_rng(2024)))
    music *= np.sqrt(np.mean(speech**2) / np.mean(music**2)) * 10 ** (-10 / 20)  # 10 dB under the voice
    return np.concatenate([music[:48000], speech + music[48000:]])


def test_the_mouth_rests_through_music_and_talks_over_it(demo, demo_speech, monkeypatch):
    """Music before the voice (made up from a seed training never drew, synthesised instruments so that
    the test is the same with or without fluidsynth) leaves the lips at rest, in files and live (the
    networks without their voice detector opened them 0.033 IOD there on average, this 0.002); speech
    laid over the same music still opens and shuts them."""
    from puppet import nonspeech
    from puppet.visemes import canonical_rest

    monkeypatch.setattr(nonspeech, "soundfont", lambda: None)
    speech = audio.load(demo_speech)
    mix = music_then_speech(speech)
    gap = opening(demo, mix)
    intro, talking = gap[5 : 3 * FPS - 5], gap[3 * FPS + 5 : -5]
    assert np.abs(intro).mean() < 0.01
    assert talking.max() > 0.12 and talking.std() > 0.03
    live, _ = lipsync.speech_offsets(mix[:48000], lipsync.shipped_predictor("streaming"))  # the music alone
    rest = canonical_rest()
    assert np.abs(lip_opening(rest[None] + live) - lip_opening(rest[None])).mean() < 0.01


def test_a_transcript_moves_the_jaw_and_lips_phone_by_phone(demo_speech):
    """With its transcript, the demo's every p/b/m shuts the lips and its vowels open them; brows, eyes
    and head stay the network's."""
    from puppet.alignment import align
    from puppet.features import MOTION_FPS
    from puppet.visemes import canonical_rest

    samples, text = audio.load(demo_speech), lipsync.read_transcript(demo_speech.with_suffix(".txt"))
    predictor = lipsync.shipped_predictor("offline")
    heard, rotation = lipsync.speech_offsets(samples, predictor)
    spoken, spoken_rotation = lipsync.speech_offsets(samples, predictor, transcript=text)
    others = [i for i in range(68) if i not in lipsync.SPOKEN_POINTS]
    assert np.array_equal(spoken[:, others], heard[:, others]) and np.array_equal(spoken_rotation, rotation)
    gap = lip_opening(canonical_rest()[None] + spoken) - lip_opening(canonical_rest()[None])  # IOD, from rest
    phones = align(samples, text)
    middle = {p.phone: [] for p in phones}
    for p in phones:
        middle[p.phone].append(int((p.start + p.end) / 2 * MOTION_FPS))
    closures = middle["P"] + middle["B"] + middle["M"]
    assert len(closures) >= 6  # Pip, puppet, me, picture, blob, much, ...
    assert gap[closures].max() < -0.04  # shut: the rest gap closed
    assert gap[middle["AE"] + middle["AH"] + middle["AA"]].max() > 0.15  # open
    assert np.abs(gap[: int(phones[0].end * MOTION_FPS) // 2]).max() < 1e-3  # at rest before the first word


def test_over_a_loud_music_bed_the_transcript_still_shuts_every_p_b_m(demo_speech, monkeypatch):
    """Music 10 dB under the voice: the network's lips stop shutting on p/b/m (there, on 4 real readers
    under 4 pieces: 0.102 IOD apart, rest 0.100); aligned under the same music, the transcript's shut."""
    from puppet import nonspeech
    from puppet.alignment import align
    from puppet.features import MOTION_FPS
    from puppet.visemes import canonical_rest

    monkeypatch.setattr(nonspeech, "soundfont", lambda: None)
    speech, text = audio.load(demo_speech), lipsync.read_transcript(demo_speech.with_suffix(".txt"))
    music = nonspeech.music(len(speech), np.random.default_rng(7)).astype(np.float32)
    music *= np.sqrt(np.mean(speech**2) / np.mean(music**2)) * 10 ** (-10 / 20)
    spoken, _ = lipsync.speech_offsets(speech + music, lipsync.shipped_predictor("offline"), transcript=text)
    gap = lip_opening(canonical_rest()[None] + spoken) - lip_opening(canonical_rest()[None])
    closures = [int((p.start + p.end) / 2 * MOTION_FPS) for p in align(speech, text) if p.phone in ("P", "B", "M")]
    assert gap[closures].max() < -0.04


def test_recognised_words_move_the_jaw_and_lips_by_their_phones(demo_speech):
    """Without a transcript, the words heard in the demo ("i bet your pocket … who knew a blob pixels
    could be this much fun") shut the lips on the p/b/m the recogniser placed and open them on its
    vowels; brows, eyes and head stay the network's; silence gives the network's mouth."""
    from puppet.alignment import heard
    from puppet.features import MOTION_FPS
    from puppet.visemes import canonical_rest

    samples = audio.load(demo_speech)
    predictor = lipsync.shipped_predictor("offline")
    network, rotation = lipsync.speech_offsets(samples, predictor)
    recognised, recognised_rotation = lipsync.speech_offsets(samples, predictor, recognise=True)
    others = [i for i in range(68) if i not in lipsync.SPOKEN_POINTS]
    assert np.array_equal(recognised[:, others], network[:, others]) and np.array_equal(recognised_rotation, rotation)
    phones = heard(samples).phones
    middle = {p.phone: [] for p in phones}
    for p in phones:
        middle[p.phone].append(int((p.start + p.end) / 2 * MOTION_FPS))
    gap = lip_opening(canonical_rest()[None] + recognised) - lip_opening(canonical_rest()[None])
    closures = middle["P"] + middle["B"] + middle["M"]
    assert len(closures) >= 6 and gap[closures].max() < -0.04
    assert gap[middle["AE"] + middle["AH"] + middle["AA"]].max() > 0.15
    silence = np.zeros(32000, np.float32)
    assert np.array_equal(lipsync.heard_mouth(network[:100] * 0, silence), network[:100] * 0)


def test_words_heard_in_music_do_not_move_a_mouth_the_network_rests(demo_speech, monkeypatch):
    """The recogniser hears words in 3 s of music before the voice (without the network's stillness
    there the lips open up to 0.14 IOD and 0.027 on average); the mouth stays at rest, and talks after."""
    from puppet import nonspeech
    from puppet.visemes import canonical_rest

    monkeypatch.setattr(nonspeech, "soundfont", lambda: None)
    speech = audio.load(demo_speech)
    mix = music_then_speech(speech).astype(np.float32)
    offsets, _ = lipsync.speech_offsets(mix, lipsync.shipped_predictor("offline"), recognise=True)
    gap = lip_opening(canonical_rest()[None] + offsets) - lip_opening(canonical_rest()[None])  # 50 fps
    assert np.abs(gap[5:145]).mean() < 0.01
    assert gap[150:].max() > 0.15 and gap[150:].min() < -0.04


def test_where_the_transcript_does_not_fit_the_mouth_follows_the_sound(demo_speech):
    from puppet.alignment import Cue
    from puppet.visemes import frame_times

    samples, text = audio.load(demo_speech), lipsync.read_transcript(demo_speech.with_suffix(".txt"))
    predictor = lipsync.shipped_predictor("offline")
    heard, _ = lipsync.speech_offsets(samples, predictor)
    duration = len(samples) / 16000
    cues = (Cue(0.0, 2.1, text.split(".")[0]), Cue(2.1, 5.2, "The quick brown fox jumps over the lazy dog."),
            Cue(5.2, duration, ".".join(text.split(".")[2:])))
    with pytest.warns(PuppetWarning, match="does not fit the audio at 0:0[23]"):
        spoken, _ = lipsync.speech_offsets(samples, predictor, transcript=cues)
    times = frame_times(len(spoken))
    mouth = lipsync.SPOKEN_POINTS
    same = np.abs(spoken[:, mouth] - heard[:, mouth]).max(axis=(1, 2)) < 1e-6
    assert same[(times > 3.2) & (times < 4.2)].all()  # inside the poor fit: the network's mouth
    assert not same[times < 2.0].all() and not same[times > 5.5].all()  # elsewhere the subtitles' phones


def test_transcripts_are_read_as_text(tmp_path):
    with pytest.raises(PuppetError, match="cannot read the transcript"):
        lipsync.read_transcript(tmp_path / "missing.txt")
    (tmp_path / "binary.txt").write_bytes(bytes(range(128, 256)))
    with pytest.raises(PuppetError, match="not UTF-8"):
        lipsync.read_transcript(tmp_path / "binary.txt")
    srt = tmp_path / "talk.srt"
    srt.write_text("1\n00:00:00,000 --> 00:00:02,500\nHi! I'm <i>Pip</i>.\n\n2\n01:00:02,5 --> 01:00:04,050\n{\\an8}Give me [laughs]\n42. ♪\n\n3\n01:00:05,000 --> 01:00:09,000\n[Music]\n")
    (hi, give, music) = lipsync.read_transcript(srt)
    assert (hi.start, hi.end, hi.text.split()) == (0.0, 2.5, ["Hi!", "I'm", "Pip", "."])
    assert (give.start, give.end, give.text.split()) == (3602.5, 3604.05, ["Give", "me", "42."])
    assert music.text.strip() == ""  # no words: the network's mouth there
    vtt = tmp_path / "talk.vtt"
    vtt.write_text("WEBVTT\n\nNOTE by hand\n\nintro\n00:01.250 --> 00:02.500 align:start\n<c.yellow>Hi</c> there\n")
    (cue,) = lipsync.read_transcript(vtt)
    assert (cue.start, cue.end, cue.text.split()) == (1.25, 2.5, ["Hi", "there"])
    (tmp_path / "bad.srt").write_text("1\n00:00:00 --> soon\nHi\n")
    with pytest.raises(PuppetError, match="cannot read the subtitle timing"):
        lipsync.read_transcript(tmp_path / "bad.srt")
    (tmp_path / "empty.vtt").write_text("WEBVTT\n\n")
    with pytest.raises(PuppetError, match="no subtitle cues"):
        lipsync.read_transcript(tmp_path / "empty.vtt")
    plain = tmp_path / "talk.txt"
    plain.write_text("Scene 2 --> the cat\n")
    assert lipsync.read_transcript(plain) == "Scene 2 --> the cat\n"  # plain text is taken as it is
