import json
import shutil
import subprocess

import numpy as np
import pytest

from puppet import audio, features
from puppet.alignment import SILENCE
from puppet.labels import FAILURES, label, main
from puppet.visemes import canonical_rest

UTTERANCES = {"one": ("Bob met my mother by the pool", "en-us"), "two": ("Five vivid voices", "en-us+f2")}


@pytest.fixture
def corpus(tmp_path):
    """A two-utterance corpus spoken by espeak-ng, laid out as the corpus builder writes it."""
    if shutil.which("espeak-ng") is None:
        pytest.skip("espeak-ng is not installed")
    (tmp_path / "audio").mkdir()
    (tmp_path / "clean").mkdir()
    lines = []
    for name, (text, voice) in UTTERANCES.items():
        subprocess.run(["espeak-ng", "-v", voice, "-w", str(tmp_path / "clean" / f"{name}.wav"), text], check=True)
        shutil.copy(tmp_path / "clean" / f"{name}.wav", tmp_path / "audio" / f"{name}.wav")
        lines.append(json.dumps({"id": name, "text": text, "speaker": voice, "heldout": False}))
    (tmp_path / "manifest.jsonl").write_text("\n".join(lines) + "\n")
    return tmp_path


def test_a_corpus_gets_phones_and_targets_of_the_networks_frame_count(corpus):
    label(corpus, workers=2)
    for name in UTTERANCES:
        samples = audio.load(corpus / "clean" / f"{name}.wav")
        phones = json.loads((corpus / "phones" / f"{name}.json").read_text())
        assert phones[0]["start"] == 0 and phones[-1]["end"] == pytest.approx(len(samples) / 16000, abs=1e-3)
        assert any(p["phone"] != SILENCE for p in phones)
        targets = np.load(corpus / "targets" / f"{name}.npz")
        frames = features.motion_frame_count(len(samples))
        assert targets["offsets"].shape == (frames, 68, 3) and targets["offsets"].dtype == np.float32
        assert targets["rotation"].shape == (frames, 3) and targets["rotation"].dtype == np.float32
        assert float(targets["fps"]) == features.MOTION_FPS
        assert np.abs(targets["offsets"]).max() < 0.5 * np.ptp(canonical_rest()[:, 0])  # offsets, not positions
    one = json.loads((corpus / "phones" / "one.json").read_text())
    closures = [p for p in one if p["phone"] in ("B", "M", "P")]
    offsets = np.load(corpus / "targets" / "one.npz")["offsets"]
    shut = [canonical_rest()[66, 1] + offsets[int((p["start"] + p["end"]) / 2 * 50), 66, 1]
            - canonical_rest()[62, 1] - offsets[int((p["start"] + p["end"]) / 2 * 50), 62, 1] for p in closures]
    assert len(closures) >= 5 and max(np.abs(shut)) < 0.02


def test_labelling_resumes_skips_unready_audio_and_logs_failures(corpus):
    label(corpus, workers=1)
    done = {path: path.stat().st_mtime_ns for path in (corpus / "targets").iterdir()}
    with open(corpus / "manifest.jsonl", "a") as manifest:  # the corpus grows
        manifest.write(json.dumps({"id": "three", "text": "the quick brown fox jumps over the lazy dog "
                                   "again and again and again", "speaker": "x", "heldout": False}) + "\n")
        manifest.write(json.dumps({"id": "four", "text": "not yet", "speaker": "x", "heldout": False}) + "\n")
        manifest.write('{"id": "five", "te')  # a line still being written
    three = corpus / "clean" / "three.wav"  # a clip far too short for its text
    three.write_bytes((corpus / "clean" / "two.wav").read_bytes()[:2000])
    assert main([str(corpus), "--workers", "1"]) == 0
    assert {path: path.stat().st_mtime_ns for path in done} == done  # finished ids untouched
    failures = [json.loads(line) for line in (corpus / FAILURES).read_text().splitlines()]
    assert [f["id"] for f in failures] == ["three"] and "cannot align" in failures[0]["error"]
    assert not (corpus / "targets" / "four.npz").exists()  # no audio yet: left for the next run
    label(corpus, workers=1)  # a failure is not retried
    assert len((corpus / FAILURES).read_text().splitlines()) == 1
