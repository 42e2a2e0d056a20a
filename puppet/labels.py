"""Training labels for a speech corpus: phones by forced alignment, then landmark motion targets.

Corpus layout (`corpus_dir`): manifest.jsonl, one JSON object per utterance with at least "id",
"text" and "speaker"; audio/ID.wav (what the network hears) and clean/ID.wav (the same speech,
same timing, without augmentation). Labelling aligns the clean copy and writes
    phones/ID.json   [{"phone": "AA", "start": 0.12, "end": 0.2}, ...] tiling the audio, seconds
    targets/ID.npz   offsets (T, 68, 3) float32 IOD units, head frame, from `visemes.canonical_rest()`
                     rotation (T, 3) float32 radians (pitch, yaw, roll), fps = MOTION_FPS
                     with T = features.motion_frame_count(samples), the network's frame count.
Finished ids are skipped, so labelling resumes and can be re-run as the manifest grows; files
appear atomically (written aside, then renamed). An utterance that cannot be aligned is logged
to label_failures.jsonl and skipped (delete that file to try them again); one whose clean audio
is not there yet is left for the next run.

    python -m puppet.labels CORPUS_DIR [--workers 2] [--follow SECONDS]
"""
import argparse
import json
import multiprocessing
import os
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
from tqdm import tqdm

from puppet import audio, features
from puppet.alignment import align
from puppet.articulation import blend, unit_offsets
from puppet.errors import PuppetError
from puppet.prosody import head_motion, style_for
from puppet.visemes import canonical_rest, mouth_motion

MANIFEST = "manifest.jsonl"
FAILURES = "label_failures.jsonl"
WORKERS = 2  # processes; each holds its own pocketsphinx decoder
FOLLOW_POLL = 10.0  # seconds between looks at a growing manifest with --follow


def motion_targets(samples: np.ndarray, phones, speaker: str) -> tuple[np.ndarray, np.ndarray]:
    """Landmark motion for one utterance: mouth from the phones, head and brows from prosody.

    samples: (N,) float32 mono speech at 16 kHz; phones: its alignment; speaker: sets the style.
    Returns offsets (T, 68, 3) float32, IOD units, head frame, from `canonical_rest()`, and
    rotation (T, 3) float32 radians; T = features.motion_frame_count(N).
    """
    n_frames = features.motion_frame_count(len(samples))
    rotation, brow = head_motion(samples, phones, n_frames, style_for(speaker))
    offsets = mouth_motion(phones, n_frames) + blend(unit_offsets(canonical_rest()), {"brow_raise": brow})
    return offsets, rotation


def _write_atomic(path: Path, write) -> None:
    """Call write(file) on a temporary file beside `path`, then rename it into place."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(temporary, "wb") as file:
        write(file)
    os.replace(temporary, path)


def label_one(corpus_dir: Path, entry: dict) -> tuple[str, str | None, float]:
    """Label one manifest entry: (id, error message or None, seconds of audio labelled)."""
    name = entry["id"]
    try:
        samples = audio.load(corpus_dir / "clean" / f"{name}.wav", features.SAMPLE_RATE)
        phones = align(samples, entry["text"])
        offsets, rotation = motion_targets(samples, phones, entry.get("speaker", ""))
    except PuppetError as error:
        return name, str(error), 0.0
    rows = [{"phone": p.phone, "start": round(p.start, 4), "end": round(p.end, 4)} for p in phones]
    _write_atomic(corpus_dir / "phones" / f"{name}.json", lambda f: f.write(json.dumps(rows).encode()))
    _write_atomic(corpus_dir / "targets" / f"{name}.npz",
                  lambda f: np.savez(f, offsets=offsets, rotation=rotation, fps=np.float32(features.MOTION_FPS)))
    return name, None, len(samples) / features.SAMPLE_RATE


def _read_jsonl(path: Path) -> list[dict]:
    """The complete lines of a JSON-lines file (a line still being written is left out)."""
    if not path.exists():
        return []
    entries = []
    for line in path.read_text().splitlines():
        try:
            entries.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return entries


def pending(corpus_dir: Path) -> list[dict]:
    """Manifest entries with clean audio on disk but no targets yet, and not logged as failed.

    The corpus builder writes audio atomically before its manifest line, so listed audio is complete.
    """
    failed = {entry["id"] for entry in _read_jsonl(corpus_dir / FAILURES)}
    return [entry for entry in _read_jsonl(corpus_dir / MANIFEST)
            if entry["id"] not in failed and not (corpus_dir / "targets" / f"{entry['id']}.npz").exists()
            and (corpus_dir / "clean" / f"{entry['id']}.wav").exists()]


def label(corpus_dir: Path, workers: int = WORKERS) -> None:
    """Label every pending utterance of the corpus in `corpus_dir` (see the module docstring)."""
    corpus_dir = Path(corpus_dir)
    if not (corpus_dir / MANIFEST).exists():
        raise PuppetError(f"no {MANIFEST} in {corpus_dir}: is it a corpus folder?")
    todo = pending(corpus_dir)
    if not todo:
        return
    (corpus_dir / "phones").mkdir(exist_ok=True)
    (corpus_dir / "targets").mkdir(exist_ok=True)
    started, seconds = time.monotonic(), 0.0
    # "spawn": forking a process that already runs torch or onnxruntime threads can deadlock.
    with multiprocessing.get_context("spawn").Pool(workers) as pool, open(corpus_dir / FAILURES, "a") as failures:
        progress = tqdm(pool.imap_unordered(partial(label_one, corpus_dir), todo),
                        total=len(todo), desc="labelling", unit="utt")
        for name, error, duration in progress:
            seconds += duration
            progress.set_postfix(audio_per_wall=f"{seconds / (time.monotonic() - started):.1f}x")
            if error is not None:
                failures.write(json.dumps({"id": name, "error": error}) + "\n")
                failures.flush()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m puppet.labels", description=__doc__.splitlines()[0])
    parser.add_argument("corpus_dir", type=Path, help="folder holding manifest.jsonl, audio/ and clean/")
    parser.add_argument("--workers", type=int, default=WORKERS, help="processes (default %(default)s)")
    parser.add_argument("--follow", type=float, default=0.0, metavar="SECONDS",
                        help="keep labelling a growing corpus until nothing new has come for this long")
    args = parser.parse_args(argv)
    try:
        label(args.corpus_dir, args.workers)
        quiet_since = time.monotonic()
        while time.monotonic() - quiet_since < args.follow:
            time.sleep(FOLLOW_POLL)
            if pending(args.corpus_dir):
                label(args.corpus_dir, args.workers)
                quiet_since = time.monotonic()
    except PuppetError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
