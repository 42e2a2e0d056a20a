"""Talking video: audio (or a motion track) → motion → mesh positions → frames → output.

The whole offline pipeline reads top to bottom in `render`; frames are rendered headless and
handed to the output as they come, so memory stays flat however long the audio is.
"""
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from puppet import audio, export, lipsync, track
from puppet.alignment import Cue
from puppet.bundle import Puppet
from puppet.errors import PuppetError
from puppet.expression import expression_offsets
from puppet.landmarks import face_scale
from puppet.life import LifeOptions, life_motion
from puppet.loudness import LoudnessOptions, frame_count, loudness_motion
from puppet.motion import Motion
from puppet.pose import posed_landmarks
from puppet.renderer import Background, Canvas, PuppetRenderer, headless_context

DEFAULT_FPS = 25.0
DEFAULT_MAX_SIDE = 1080  # default output: the portrait's own size, no larger than this
FOREIGN_TRACK = 0.25  # a track whose landmarks sit this far (IOD, median) from the portrait's is another face's
CHUNK_FRAMES = 250  # frames posed at a time (10 s at 25 fps): bounds memory on long inputs
MOTION_SOURCES = ("learned", "loudness")  # built-in sources; anything else given to --motion is a track file


@dataclass(frozen=True)
class VideoOptions:
    size: tuple[int, int] | None = None  # output (width, height); None: the portrait's size, capped
    fps: float = DEFAULT_FPS  # output frames per second
    background: Background | None = None  # None: transparent for PNG frames, white for video
    samples: int = 0  # MSAA samples per pixel (0: none; the mouth rim is smoothed in the shader)
    motion: str = "loudness"  # a built-in source name or a track file (.npz)
    loudness: LoudnessOptions = field(default_factory=LoudnessOptions)  # the baseline's settings
    life: LifeOptions = field(default_factory=LifeOptions)  # blinks, idle head motion, breathing
    expression: str = "neutral"  # a mood held through the clip (puppet.expression.EXPRESSIONS)
    transcript: str | tuple[Cue, ...] | None = None  # the words spoken (text or subtitle cues): the learned motion's jaw and lips follow their phones
    recognise: bool = False  # no transcript: the learned motion's jaw and lips follow the phones of the words recognised in the audio


def default_motion() -> str:
    """The learned lip-sync network when this install has one, else the loudness baseline."""
    return "learned" if lipsync.has_model() else "loudness"


def output_size(image_size: tuple[int, int], max_side: int = DEFAULT_MAX_SIDE) -> tuple[int, int]:
    """(width, height): the portrait's size scaled to at most `max_side`, rounded to even numbers."""
    scale = min(1.0, max_side / max(image_size))
    return tuple(max(2, 2 * round(side * scale / 2)) for side in image_size)


def make_motion(puppet: Puppet, audio_path: Path | None, options: VideoOptions) -> Motion:
    """The puppet's motion from the chosen source, at options.fps."""
    rest = puppet.rig.landmarks
    if options.transcript is not None and options.motion != "learned":
        raise PuppetError("a transcript drives the learned motion only, not --motion loudness or a track")
    if options.recognise and (options.motion != "learned" or options.transcript is not None):
        raise PuppetError("recognising the words drives the learned motion only, and only without a transcript")
    if options.motion in MOTION_SOURCES:
        if audio_path is None:
            raise PuppetError(f"the {options.motion} motion needs an audio file")
        samples = audio.load(audio_path)
        audio.check_audible(samples, str(audio_path))
        if options.motion == "learned":
            if not lipsync.has_model():
                raise PuppetError("this install has no trained lip-sync model: run `puppet train`, or use --motion loudness")
            frames = frame_count(len(samples), audio.ANALYSIS_RATE, options.fps)
            speech = lipsync.learned_motion(samples, rest, options.fps, frames, transcript=options.transcript,
                                            recognise=options.recognise)
        else:
            speech = loudness_motion(samples, audio.ANALYSIS_RATE, rest, options.fps, options.loudness)
        activity = _activity(speech)
        motion = speech + life_motion(len(speech), options.fps, rest, options.life, activity)
        return replace(motion, offsets=motion.offsets + expression_offsets(rest, options.expression))
    landmarks, fps = track.read(options.motion)
    if abs(fps - options.fps) > 1e-6:
        raise PuppetError(f"{options.motion} is at {fps:g} fps; render it with --fps {fps:g}")
    motion = track.motion_from_track(landmarks, rest, fps)
    if np.median(np.linalg.norm(motion.offsets[..., :2], axis=2)) > FOREIGN_TRACK * face_scale(rest):
        raise PuppetError(f"{options.motion} moves another face than this portrait's (make it with --landmarks-out, or puppet predict --face with this portrait's landmarks)")
    return motion


def _activity(speech: Motion) -> np.ndarray:
    """(T,) float32 in [0, 1]: how much the mouth is moving, to liven idle head motion while talking."""
    jaw = np.abs(speech.offsets[:, 57, 1])
    return np.clip(jaw / max(float(jaw.max()), 1e-6), 0, 1).astype(np.float32)


def render(
    puppet: Puppet,
    audio_path: Path | None,
    output: Path,
    options: VideoOptions = VideoOptions(),
    force: bool = False,
    landmarks_out: Path | None = None,
    progress: bool = True,
) -> Path:
    """Render the talking puppet to `output` (a video file or a folder of RGBA PNG frames)."""
    output = export.check_output(output, force)
    if landmarks_out is not None:
        landmarks_out = check_track_output(landmarks_out, force)
    motion = make_motion(puppet, audio_path, options)
    size = options.size or output_size(puppet.rig.image_size)
    background = options.background or (Background() if output.suffix == "" else Background((1.0, 1.0, 1.0, 1.0)))

    ctx = headless_context()
    try:
        renderer = PuppetRenderer(ctx, puppet.image, puppet.rig)
        canvas = Canvas(ctx, size, options.samples)
        with export.open_output(output, size, options.fps, audio_path=audio_path, force=force) as out:
            bar = tqdm(total=len(motion), unit="frame", desc=f"rendering {output.name}", disable=not progress, leave=False)
            for start in range(0, len(motion), CHUNK_FRAMES):
                for positions in puppet.rig.animate(motion[start : start + CHUNK_FRAMES]):
                    canvas.begin(background)
                    renderer.draw(positions, size)
                    out.send(canvas.read())
                    bar.update()
            bar.close()
    finally:
        ctx.release()
    if landmarks_out is not None:
        track.write(landmarks_out, posed_landmarks(puppet.rig.landmarks, motion), motion.fps)
    return output



def check_track_output(path: Path, force: bool) -> Path:
    """The --landmarks-out path, checked before any work: an .npz in an existing folder."""
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise PuppetError(f"--landmarks-out must name an .npz file, not {path}")
    if not path.parent.is_dir():
        raise PuppetError(f"output folder does not exist: {path.parent}")
    if path.exists() and not force:
        raise PuppetError(f"{path} exists; use --force to overwrite")
    return path
