"""Scores for lip-sync motion: MakeItTalk's metrics (§5.3) on held-out synthetic voices and on
real talking videos, for any motion source beside the baselines.

Every source is a function from 16 kHz speech to canonical offsets `(T, 68, 3)` at MOTION_FPS
(inter-ocular-distance units, head frame; see `puppet.visemes.canonical_rest`) and a head
rotation `(T, 3)`, or None for a still head. Real videos are
tracked with the project's own detector; each frame is aligned to the canonical face by a
similarity fit on the stable points (eye corners, nose), which removes head pose. The speaker's
own rest face q is the per-landmark median of the clip's frames with the most closed lips (the
lowest REST_QUANTILE of inner-lip opening): the face at rest, as a portrait shows it and as the
network's offsets start from (its silence is lips together). A prediction is q plus the source's
offsets (q + Δq, as in the paper); the static face is q held still. (The clip's median face is not
a rest: mid-speech, its lips are half open, and offsets added to it open the mouth twice.)

Metrics (lower is better, except the correlation):
- D-LL / D-VL: mean distance of jaw and lip landmarks / of their frame-to-frame velocities,
  as a percentage of the reference's widest mouth (corner to corner) in the clip;
- D-A: mean difference of the inner-mouth area, as a percentage of the reference's largest;
- D-L / D-V: the same as D-LL / D-VL over all 68 landmarks, as a percentage of the face width;
- D-Rot: mean head-rotation difference in degrees (synthetic voices only, where it is known);
- lip correlation: Pearson correlation of predicted and real inner-lip opening.

`score_labels` turns the same metrics on the training labels themselves: motion made from the
aligner's phones against motion made from the phones at the synthesizer's own times.
"""
import json
from pathlib import Path
from typing import Callable

import av
import numpy as np

from puppet import audio
from puppet import landmarks as lm
from puppet.detect import track
from puppet.errors import PuppetError
from puppet.features import MOTION_FPS, SAMPLE_RATE, motion_frame_count
from puppet.motion import resample

# (N,) float32 16 kHz speech → ((T, 68, 3) canonical offsets, (T, 3) head rotation or None: a still head)
Source = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray | None]]
JAW_AND_LIPS = list(lm.JAW) + list(lm.MOUTH)
REST_QUANTILE = 0.1  # share of a real clip's frames, the most closed, whose median face is its rest
STABLE_POINTS = [36, 39, 42, 45, 27, 28, 29, 30, 31, 33, 35]  # eye corners, nose: no speech motion


def mouth_area(points: np.ndarray) -> np.ndarray:
    """(T,) area of the inner-lip polygon (60–67) of (T, 68, ≥2) points (shoelace formula)."""
    ring = points[:, list(lm.INNER_LIP), :2]
    x, y = ring[..., 0], ring[..., 1]
    return 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))


def lip_opening(points: np.ndarray) -> np.ndarray:
    """(T,) mean distance between facing inner-lip points of (T, 68, ≥2) points."""
    upper, lower = zip(*lm.INNER_LIP_PAIRS)
    return np.linalg.norm(points[:, list(upper), :2] - points[:, list(lower), :2], axis=2).mean(axis=1)


def metrics(predicted: np.ndarray, reference: np.ndarray) -> dict:
    """D-LL, D-VL, D-A, D-L, D-V (%) and lip correlation of (T, 68, ≥2) predicted vs reference points."""
    p, r = predicted[..., :2], reference[..., :2]
    mouth_width = np.linalg.norm(r[:, 54] - r[:, 48], axis=1).max()
    face_width = np.linalg.norm(r[:, 16] - r[:, 0], axis=1).max()
    velocity = np.diff(p, axis=0) - np.diff(r, axis=0)
    area = mouth_area(r)
    opening_p, opening_r = lip_opening(p), lip_opening(r)
    spread = opening_p.std() * opening_r.std()
    return {
        "D-LL": 100 * np.linalg.norm(p[:, JAW_AND_LIPS] - r[:, JAW_AND_LIPS], axis=2).mean() / mouth_width,
        "D-VL": 100 * np.linalg.norm(velocity[:, JAW_AND_LIPS], axis=2).mean() / mouth_width,
        "D-A": 100 * np.abs(mouth_area(p) - area).mean() / max(area.max(), 1e-9),
        "D-L": 100 * np.linalg.norm(p - r, axis=2).mean() / face_width,
        "D-V": 100 * np.linalg.norm(velocity, axis=2).mean() / face_width,
        "lip_corr": float(np.mean((opening_p - opening_p.mean()) * (opening_r - opening_r.mean())) / spread) if spread > 0 else 0.0,
    }


def align_to(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(T, 68, 2) points moved by the per-frame similarity (rotation, scale, shift) that best maps
    their STABLE_POINTS onto those of (68, 2) target."""
    aligned = np.empty_like(points[..., :2])
    dst = target[STABLE_POINTS, :2]
    dst_centre = dst.mean(0)
    for t, frame in enumerate(points[..., :2]):
        src = frame[STABLE_POINTS]
        src_centre = src.mean(0)
        a, b = src - src_centre, dst - dst_centre
        u, s, vt = np.linalg.svd(a.T @ b)
        flip = np.diag([1.0, np.sign(np.linalg.det(u @ vt))])
        rotation = u @ flip @ vt
        scale = np.trace(np.diag(s) @ flip) / max(np.sum(a**2), 1e-12)
        aligned[t] = (frame - src_centre) @ rotation * scale + dst_centre
    return aligned


def rest_face(points: np.ndarray) -> np.ndarray:
    """(68, 2) a speaker's rest face from (T, 68, 2) aligned frames of speech: the per-landmark median
    of the frames with the most closed lips (the lowest REST_QUANTILE of inner-lip opening)."""
    opening = lip_opening(points)
    return np.median(points[opening <= np.quantile(opening, REST_QUANTILE)], axis=0)


def video_reference(path: Path, cache: Path | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Real landmarks of a talking video: ((T, 68, 2) float32 pixels, fps, (N,) float32 16 kHz audio).

    Tracking is slow (about 20 frames/s), so results are cached as `cache/NAME.npz` when given.
    """
    cached = cache / f"{path.stem}.npz" if cache else None
    samples = audio.load(path)
    if cached and cached.is_file():
        data = np.load(cached)
        return data["landmarks"], float(data["fps"]), samples
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            fps = float(stream.average_rate)
            points = track(frame.to_ndarray(format="rgb24") for frame in container.decode(stream))
    except (av.FFmpegError, IndexError) as error:
        raise PuppetError(f"cannot read video frames from {path}: {error}") from None
    if cached:
        cached.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cached, landmarks=points, fps=fps)
    return points, fps, samples


def video_predictions(path: Path, sources: dict[str, Source], canonical: np.ndarray, cache: Path | None = None):
    """One real video, aligned to canonical (68, 3) IOD units: (real (T, 68, 2), {source name:
    predicted (T, 68, 2)}, fps), over the T frames where the face was found."""
    points, fps, samples = video_reference(path, cache)
    valid = ~np.isnan(points).any(axis=(1, 2))
    aligned = align_to(points[valid], canonical)
    rest = rest_face(aligned)
    predicted = {}
    for name, source in sources.items():
        offsets = resample(source(samples)[0], MOTION_FPS, fps, len(points))[valid]
        predicted[name] = rest[None] + offsets[..., :2]
    return aligned, predicted, fps


def score_video(path: Path, sources: dict[str, Source], canonical: np.ndarray, cache: Path | None = None, plot: Path | None = None) -> dict:
    """{source name: metrics} for one real video; canonical: (68, 3) canonical rest (IOD units).
    With `plot`, a picture of its lip opening is written there too (see plot_openings)."""
    real, predicted, fps = video_predictions(path, sources, canonical, cache)
    scores = {name: metrics(points, real) for name, points in predicted.items()}
    if plot is not None:
        plot_openings(path.name, real, predicted, {name: s["lip_corr"] for name, s in scores.items()}, fps, plot)
    return scores


PLOT_COLOURS = {"real": (20, 20, 20), "learned": (200, 90, 30), "learned-live": (230, 170, 90), "recognised": (60, 170, 60), "loudness": (60, 140, 230)}  # BGR


def plot_openings(title: str, real: np.ndarray, predicted: dict[str, np.ndarray], correlations: dict[str, float],
                  fps: float, out: Path) -> None:
    """A picture of a video's inner-lip opening over time, written to `out` (.png or .jpg): a row
    per moving source, its curve over the real one, labelled with its lip correlation.
    real, predicted: (T, 68, 2) as video_predictions."""
    import cv2

    curves = {name: lip_opening(points) for name, points in predicted.items() if name != "static"}
    width, row, margin = 1200, 150, 40
    picture = np.full((margin + row * len(curves), width, 3), 255, np.uint8)
    truth = lip_opening(real)
    top = max(truth.max(), *(c.max() for c in curves.values()), 1e-6)
    seconds = len(truth) / fps
    cv2.putText(picture, f"{title}: inner-lip opening (IOD units, 0 to {top:.2f}) over {seconds:.1f} s",
                (10, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    x = np.linspace(10, width - 10, len(truth))
    for i, (name, curve) in enumerate(curves.items()):
        base = margin + row * (i + 1) - 12
        cv2.line(picture, (10, base), (width - 10, base), (210, 210, 210), 1)
        for values, colour in ((truth, PLOT_COLOURS["real"]), (curve, PLOT_COLOURS.get(name, (120, 120, 120)))):
            line = np.stack([x, base - values / top * (row - 44)], axis=1).round().astype(np.int32)
            cv2.polylines(picture, [line], False, colour, 2, cv2.LINE_AA)
        cv2.putText(picture, f"real (black) vs {name}: correlation {correlations[name]:.2f}", (14, base - row + 26),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.55, PLOT_COLOURS.get(name, (120, 120, 120)), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(out), picture):
        raise PuppetError(f"cannot write {out} (give a .png or .jpg path in an existing folder)")


def score_synthetic(items: list[tuple[np.ndarray, np.ndarray, np.ndarray]], sources: dict[str, Source], canonical: np.ndarray) -> dict:
    """{source name: metrics averaged over utterances} on held-out synthetic voices.

    items: (samples (N,), target offsets (T, 68, 3), target rotation (T, 3)); a source returns
    (offsets, rotation or None: a still head) for samples.
    """
    totals: dict[str, list[dict]] = {name: [] for name in sources}
    for samples, offsets, rotation in items:
        reference = canonical[None] + offsets
        for name, source in sources.items():
            predicted_offsets, predicted_rotation = source(samples)
            frames = min(len(predicted_offsets), len(offsets))
            scores = metrics(canonical[None] + predicted_offsets[:frames], reference[:frames])
            if predicted_rotation is None:  # a source without head motion holds the head still
                predicted_rotation = np.zeros_like(rotation)
            scores["D-Rot"] = float(np.degrees(np.abs(predicted_rotation[:frames] - rotation[:frames])).mean())
            totals[name].append(scores)
    return {name: {key: float(np.mean([s[key] for s in runs])) for key in runs[0]} for name, runs in totals.items() if runs}


def baselines(canonical: np.ndarray) -> dict[str, Source]:
    """The sources every run scores: the learned networks as files get them, at rest in pauses (when this
    install has them: "learned" is what files are rendered with, the offline and streaming models
    averaged, "learned-live" the streaming model alone, as live, "recognised" files rendered with
    --recognise: the jaw and lips from the words recognised in the audio), the loudness baseline and a static
    face; each maps 16 kHz speech to (offsets (T, 68, 3), rotation (T, 3) | None)."""
    from puppet import lipsync, speaker
    from puppet.loudness import loudness_motion

    def static(samples):
        return np.zeros((motion_frame_count(len(samples)), lm.N_LANDMARKS, 3), np.float32), None

    def loudness(samples):
        return loudness_motion(samples, SAMPLE_RATE, canonical, MOTION_FPS).offsets, None

    sources = {"static": static, "loudness": loudness}
    if lipsync.has_model():
        heard = {"samples": None, "embedding": None}  # both networks score one clip after the other: embed it once

        def embedding(samples):
            if heard["samples"] is not samples:
                heard.update(samples=samples, embedding=speaker.embed(samples))
            return heard["embedding"]

        def learned(predictor, recognise=False):
            return lambda samples: lipsync.speech_offsets(samples, predictor(), embedding(samples), recognise=recognise)

        sources = {"learned": learned(lipsync.file_predictor), "learned-live": learned(lambda: lipsync.shipped_predictor("streaming")),
                   "recognised": learned(lipsync.file_predictor, recognise=True), **sources}
    return sources


def score_corpus(corpus: Path, limit: int) -> dict:
    """Metrics on up to `limit` labelled utterances of a corpus's held-out speakers."""
    from puppet.visemes import canonical_rest

    manifest = corpus / "manifest.jsonl"
    if not manifest.is_file():
        raise PuppetError(f"{corpus} is not a corpus folder (no manifest.jsonl)")
    entries = [json.loads(line) for line in manifest.read_text().splitlines() if line.strip()]
    held = [e for e in entries if e.get("heldout") and (corpus / "targets" / f"{e['id']}.npz").is_file()][:limit]
    if not held:
        raise PuppetError(f"{corpus} has no labelled held-out utterances (run puppet train first)")
    items = []
    for entry in held:
        target = np.load(corpus / "targets" / f"{entry['id']}.npz")
        items.append((audio.load(corpus / "audio" / f"{entry['id']}.wav"), target["offsets"], target["rotation"]))
    canonical = canonical_rest()
    return score_synthetic(items, baselines(canonical), canonical)


def score_videos(folder: Path, cache: Path | None = None, plots: Path | None = None) -> dict:
    """Metrics averaged over the talking videos in a folder (each video counts once); with `plots`,
    a picture of each video's lip opening is written there as NAME.png (see plot_openings)."""
    from puppet.visemes import canonical_rest

    videos = sorted(p for p in Path(folder).glob("*") if p.suffix.lower() in (".mp4", ".mov", ".mkv"))
    if not videos:
        raise PuppetError(f"no .mp4/.mov/.mkv videos in {folder}")
    canonical = canonical_rest()
    sources = baselines(canonical)
    cache = cache or Path.home() / ".cache" / "puppet" / "tracks"
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
    per_video = [score_video(path, sources, canonical, cache, plots / f"{path.stem}.png" if plots else None) for path in videos]
    return {name: {key: float(np.mean([v[name][key] for v in per_video])) for key in per_video[0][name]} for name in sources}


CLOSURES = {"P", "B", "M"}
OPEN_VOWELS = {"AA", "AE", "AH", "AO", "AW", "AY"}
ROUNDED = {"UW", "UH", "OW", "W"}
SPREAD = {"IY", "IH", "EY"}
LONG_SILENCE = 0.3  # seconds: silences at least this long count as rest


def score_phones(folder: Path) -> dict:
    """What the mouth does on each kind of sound in real recordings with transcripts
    (`NAME.wav` + `NAME.txt`), aligned with puppet's own aligner. Per source, in IOD units:
    inner-lip opening at the centres of p/b/m, of open vowels and in long silences, and mouth
    width on oo/w over width on ee (below 1: the lips round)."""
    from puppet.alignment import align
    from puppet.visemes import canonical_rest

    clips = sorted(p for p in Path(folder).glob("*.wav") if p.with_suffix(".txt").is_file())
    if not clips:
        raise PuppetError(f"no NAME.wav + NAME.txt pairs in {folder}")
    canonical = canonical_rest()
    sources = baselines(canonical)
    found: dict[str, dict[str, list]] = {name: {k: [] for k in ("closure", "open", "silence", "rounded", "spread")} for name in sources}
    for clip in clips:
        samples = audio.load(clip)
        phones = align(samples, clip.with_suffix(".txt").read_text())
        for name, source in sources.items():
            points = canonical[None] + source(samples)[0]
            opening = lip_opening(points)
            width = np.linalg.norm(points[:, 54, :2] - points[:, 48, :2], axis=1)
            for phone in phones:
                frame = min(int((phone.start + phone.end) / 2 * MOTION_FPS), len(points) - 1)
                kind = ("closure" if phone.phone in CLOSURES else "open" if phone.phone in OPEN_VOWELS else
                        "silence" if phone.phone == "SIL" and phone.end - phone.start >= LONG_SILENCE else None)
                if kind:
                    found[name][kind].append(opening[frame])
                if phone.phone in ROUNDED or phone.phone in SPREAD:
                    found[name]["rounded" if phone.phone in ROUNDED else "spread"].append(width[frame])
    rest = float(lip_opening(canonical[None])[0])
    return {
        name: {
            "rest_gap": rest,
            "p/b/m_gap": float(np.mean(v["closure"])),
            "vowel_gap": float(np.mean(v["open"])),
            "silence_gap": float(np.mean(v["silence"])) if v["silence"] else float("nan"),
            "oo/ee_width": float(np.mean(v["rounded"]) / np.mean(v["spread"])),
        }
        for name, v in found.items()
    }


AUDIO_SUFFIXES = (".wav", ".flac", ".mp3", ".ogg", ".oga", ".opus", ".m4a", ".aac")


def score_sounds(folder: Path) -> dict:
    """What the mouth does on audio where nobody speaks (music, noise, typing: every audio file in a
    folder). Per source, in IOD units: the inner-lip opening averaged over each file's frames, then
    over the files (mean), and its largest file mean (worst); the canonical face rests at rest_gap."""
    from puppet.visemes import canonical_rest

    files = sorted(p for p in Path(folder).glob("*") if p.suffix.lower() in AUDIO_SUFFIXES)
    if not files:
        raise PuppetError(f"no audio files ({', '.join(AUDIO_SUFFIXES)}) in {folder}")
    canonical = canonical_rest()
    sources = baselines(canonical)
    found: dict[str, list[float]] = {name: [] for name in sources}
    for path in files:
        samples = audio.load(path)
        for name, source in sources.items():
            found[name].append(float(lip_opening(canonical[None] + source(samples)[0]).mean()))
    rest = float(lip_opening(canonical[None])[0])
    return {name: {"rest_gap": rest, "mean_gap": float(np.mean(v)), "worst_gap": float(np.max(v))} for name, v in found.items()}


def score_labels(sentences: int, voices: tuple[str, ...] = ("kal_diphone", "cmu_us_slt_arctic_hts")) -> dict:
    """How exact the training labels are: festival says corpus-like sentences (its voices in turn),
    and the mouth motion made from puppet's aligned phones is scored against the motion made from the
    phones at festival's own times, the truth. For scale, "1 frame late" is that truth 20 ms late.
    Also the phone boundaries' errors: for each true boundary, the nearest aligned one (ms)."""
    from puppet.alignment import align
    from puppet.corpus import (
        engine_available,
        festival_has,
        festival_timed,
        sample_texts,
    )
    from puppet.visemes import canonical_rest, mouth_motion

    voices = tuple(v for v in voices if engine_available("festival") and festival_has(v))
    if not voices:
        raise PuppetError("scoring the labels needs festival and its voice kal_diphone or cmu_us_slt_arctic_hts "
                          "(apt-get install festival festvox-kallpc16k festvox-us-slt-hts)")
    canonical = canonical_rest()
    scores: dict[str, list[dict]] = {"aligned": [], "1 frame late": []}
    errors = []
    for i, text in enumerate(sample_texts(sentences)):
        samples, truth = festival_timed(voices[i % len(voices)], text)
        aligned = align(samples, text)
        frames = motion_frame_count(len(samples))
        reference = canonical[None] + mouth_motion(truth, frames)
        scores["aligned"].append(metrics(canonical[None] + mouth_motion(aligned, frames), reference))
        scores["1 frame late"].append(metrics(np.concatenate([reference[:1], reference[:-1]]), reference))
        starts = np.array([p.start for p in aligned[1:]])
        errors += [1000 * np.abs(starts - p.start).min() for p in truth[1:]]
    table = {name: {key: float(np.mean([s[key] for s in runs])) for key in runs[0]} for name, runs in scores.items()}
    boundaries = {"median_ms": float(np.median(errors)), "p90_ms": float(np.percentile(errors, 90)),
                  "within_20ms": float(np.mean(np.array(errors) <= 20))}
    return {"motion": table, "boundaries": boundaries}


def format_table(title: str, scores: dict) -> str:
    """A plain-text table of {source: {metric: value}}."""
    keys = list(next(iter(scores.values())))
    widths = [max(10, len(k) + 2) for k in keys]
    lines = [title, f"{'source':<12}" + "".join(f"{k:>{w}}" for k, w in zip(keys, widths))]
    for name, values in scores.items():
        lines.append(f"{name:<12}" + "".join(f"{values[k]:>{w}.3f}" for k, w in zip(keys, widths)))
    return "\n".join(lines)

