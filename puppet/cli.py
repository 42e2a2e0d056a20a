"""The `puppet` command: argument parsing and the one place errors become one-line messages."""
import argparse
import os
import sys
import warnings
from dataclasses import replace
from pathlib import Path

from puppet.errors import NoFaceError, PuppetError, PuppetWarning
from puppet.template import POINTS_HELP

EXPRESSION_NAMES = ("neutral", "happy", "angry", "surprised", "sad")  # puppet.expression.EXPRESSIONS, without importing numpy for --help

NAMED_COLOURS = {
    "white": "#ffffff",
    "black": "#000000",
    "green": "#00b140",  # chroma-key green
    "blue": "#0047bb",  # chroma-key blue
    "magenta": "#ff00ff",
    "grey": "#808080",
}


def parse_size(text: str) -> tuple[int, int] | int:
    """'640x480' → (640, 480); '512' → 512 (the longer side)."""
    try:
        if "x" in text.lower():
            width, height = (int(v) for v in text.lower().split("x"))
            size = (width, height)
        else:
            size = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT or one number, got {text!r}") from None
    sides = size if isinstance(size, tuple) else (size,)
    if any(s < 16 or s > 4096 for s in sides):
        raise argparse.ArgumentTypeError("sizes must be between 16 and 4096 pixels")
    return size


def parse_background(text: str):
    """'transparent', a colour name or '#rrggbb[aa]' → renderer.Background."""
    from puppet.renderer import Background

    text = NAMED_COLOURS.get(text.lower(), text)
    if text.lower() == "transparent":
        return Background()
    digits = text.lstrip("#")
    if len(digits) not in (6, 8) or any(c not in "0123456789abcdefABCDEF" for c in digits):
        raise argparse.ArgumentTypeError(f"expected 'transparent', one of {', '.join(NAMED_COLOURS)} or #rrggbb, got {text!r}")
    values = [int(digits[i : i + 2], 16) / 255 for i in range(0, len(digits), 2)]
    return Background(tuple(values + [1.0] * (4 - len(values))))


class OneLineParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line (what was wrong, where to look), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="puppet", description="Make any portrait talk: give it a picture and speech, get a talking puppet.")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    render = commands.add_parser(
        "render",
        help="render a talking video (or PNG frames) from a portrait and audio",
        description="Render a talking video from a portrait (image or puppet bundle) and speech audio.",
        epilog="examples:\n  puppet render --demo -o demo.mp4\n  puppet render face.jpg speech.wav -o talk.mp4\n"
        "  puppet render cartoon.png speech.mp3 --landmarks cartoon.txt -o frames/ --background transparent",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    render.add_argument("input", nargs="?", type=Path, help="portrait image (PNG/JPEG/...) or puppet bundle folder")
    render.add_argument("audio", nargs="?", type=Path, help="speech: wav, flac, mp3, ogg, m4a, ... (any rate, mono or stereo)")
    render.add_argument("-o", "--output", type=Path, required=True, help="output .mp4/.mov/.mkv, or a folder name (no suffix) for RGBA PNG frames")
    render.add_argument("--demo", action="store_true", help="use the bundled character and speech clip")
    _add_rigging_arguments(render)
    render.add_argument("--motion", help="motion source: 'learned' (the lip-sync network; the default when installed), 'loudness' (a volume-driven baseline) or a track .npz (from --landmarks-out or puppet predict)")
    render.add_argument("--transcript", type=Path, metavar="TEXT_FILE", help="the words spoken (UTF-8 text, or .srt/.vtt subtitles: each cue aligned within its own times; English): the jaw and lips follow their phones, aligned to the audio; sharper than the network alone on p/b/m and oo/w")
    render.add_argument("--recognise", action="store_true", help="no transcript? recognise the words spoken (English) and move the jaw and lips from their phones as --transcript does: sharper p/b/m and oo/w than the network alone; about 25 s a minute of speech")
    render.add_argument("--size", type=parse_size, help="output WIDTHxHEIGHT, or one number for the longer side (default: the portrait's size, at most 1080)")
    render.add_argument("--fps", type=float, default=25.0, help="frames per second (default 25)")
    render.add_argument("--background", type=parse_background, help="'transparent', white, black, green, blue, magenta, grey or #rrggbb (default: transparent for frames, white for video)")
    render.add_argument("--msaa", type=int, default=4, choices=(0, 2, 4, 8), help="anti-aliasing samples per pixel (default 4)")
    render.add_argument("--seed", type=int, default=0, help="seed for blinks and idle motion (default 0)")
    render.add_argument("--expression", choices=list(EXPRESSION_NAMES), default="neutral", help="a mood held through the clip: brows, eyes, mouth corners (default neutral)")
    render.add_argument("--landmarks-out", type=Path, help="also write the motion track (.npz: landmarks (T,68,3), fps)")
    render.add_argument("-f", "--force", action="store_true", help="overwrite existing outputs")
    render.add_argument("-q", "--quiet", action="store_true", help="no progress bar")

    rig = commands.add_parser(
        "rig",
        help="rig a portrait into a puppet bundle (landmarks + mesh) you can check and reuse",
        description="Rig a portrait: find (or take) its 68 landmarks, build the mesh, save a puppet bundle folder with a preview.png.",
        epilog="examples:\n  puppet rig photo.jpg\n  puppet rig cartoon.png --landmarks cartoon.txt -o cartoon.puppet\n"
        "  puppet rig monster.png --points 210,240 300,238 256,300 220,350 292,352",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rig.add_argument("image", type=Path, help="portrait image (or, with --edit, a bundle to edit again)")
    rig.add_argument("-o", "--output", type=Path, help="bundle folder to write (default: IMAGE's name + .puppet beside it)")
    _add_rigging_arguments(rig)
    rig.add_argument("--edit", action="store_true", help="open the rig editor: drag any landmark, preview (Space), save (S)")
    rig.add_argument("-f", "--force", action="store_true", help="overwrite an existing bundle")

    live = commands.add_parser(
        "live",
        help="the puppet in a window, lip-synced to your microphone (and into OBS as a virtual camera)",
        description="Open a window where the portrait talks with your microphone: streaming lip sync, blinks, idle "
        "motion and expression hotkeys (press H in the window). --virtual-camera also sends it to OBS, Zoom, Meet, ...; "
        "--audio FILE drives the same pipeline from a recording played back in sync.",
        epilog="examples:\n  puppet live --demo\n  puppet live cartoon.puppet --virtual-camera --background green\n"
        "  puppet live face.jpg --device 'USB'      (see --list-devices)\n"
        "  puppet live --demo --audio speech.wav --duration 10 --stats stats.json\n\n"
        "latency: the window's readout (F) says how far the picture trails your voice; delay the microphone\n"
        "by that much in OBS (Audio Mixer > Advanced Audio Properties > Sync Offset) so voice and lips line up.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    live.add_argument("input", nargs="?", type=Path, help="portrait image or puppet bundle folder")
    live.add_argument("--demo", action="store_true", help="use the bundled character")
    _add_rigging_arguments(live)
    live.add_argument("--list-devices", action="store_true", help="list audio input devices and exit")
    live.add_argument("--device", metavar="DEVICE", help="microphone: index or part of its name (default: the system's default input)")
    live.add_argument("--audio", type=Path, metavar="FILE", help="drive the puppet from this recording instead of the microphone, played back in sync")
    live.add_argument("--no-playback", action="store_true", help="with --audio: do not play the recording aloud")
    live.add_argument("--loop", action="store_true", help="with --audio: start the recording again at its end")
    live.add_argument("--virtual-camera", action="store_true", help="also send frames to the system virtual camera (OBS Virtual Camera, v4l2loopback), over the key colour")
    live.add_argument("--camera-device", metavar="DEVICE", help="the virtual camera device to use (e.g. /dev/video2)")
    live.add_argument("--camera-fps", type=float, default=30.0, metavar="FPS", help="frames per second sent to the virtual camera (default 30)")
    live.add_argument("--background", type=parse_background, metavar="COLOUR", help="'transparent' (the default: a see-through window where the desktop allows, else the key colour) or a colour: green, blue, magenta, #rrggbb ...")
    live.add_argument("--size", type=parse_size, help="window and camera WIDTHxHEIGHT, or one number for the longer side (default: the portrait's shape, at most 720 on the longer side)")
    live.add_argument("--fps", type=float, help="frames per second (default: the display's refresh rate)")
    live.add_argument("--msaa", type=int, default=0, choices=(0, 2, 4, 8), help="anti-aliasing samples per pixel (default 0: the mouth rim is smoothed in the shader anyway)")
    live.add_argument("--expression", choices=list(EXPRESSION_NAMES), help="starting expression (keys 1-5 change it)")
    live.add_argument("--sensitivity", type=float, metavar="DB", help="voice gain in dB (keys + and -); saved with the puppet")
    live.add_argument("--gate", type=float, metavar="DBFS", help="noise gate in dBFS: quieter sound counts as silence (keys [ and ]; it also rises to 6 dB above the room's noise by itself); saved with the puppet")
    live.add_argument("--blink-rate", type=float, metavar="PER_MINUTE", help="blinks per minute (keys , and .); saved with the puppet")
    live.add_argument("--blink-randomness", type=float, metavar="SPREAD", help="spread of the gaps between blinks, 0 (metronome) to 2 (default 0.5); saved with the puppet")
    live.add_argument("--push-to-talk", action="store_true", help="the mouth moves only while Space is held (key T toggles)")
    live.add_argument("--show-stats", action="store_true", help="show fps and latency in the window (key F toggles)")
    live.add_argument("--duration", type=float, metavar="SECONDS", help="stop after this many seconds")
    live.add_argument("--stats", type=Path, metavar="FILE", help="on exit, write fps, latency percentiles and dropped frames to this JSON file")
    live.add_argument("--no-window", action="store_true", help="render offscreen without a window (with --virtual-camera on a machine without a desktop, or for --stats)")
    live.add_argument("--seed", type=int, default=0, help="seed for blinks and idle motion (default 0)")
    live.add_argument("-f", "--force", action="store_true", help="overwrite an existing --stats file")

    predict = commands.add_parser(
        "predict",
        help="speech → a motion track (.npz) of a face's 68 landmarks, from the lip-sync network",
        description="Predict the motion of a face's 68 landmarks from speech with the trained network: "
        "the face's own landmarks put in motion (lips, expression, head, blinks). Render it with "
        "`puppet render IMAGE AUDIO --motion TRACK.npz`.",
    )
    predict.add_argument("audio", type=Path, help="speech: any format FFmpeg reads")
    predict.add_argument("--face", type=Path, help="the face's 68 landmarks (text, .json or .npy; pixels); default: puppet's canonical face in a 512×512 frame")
    predict.add_argument("-o", "--output", type=Path, required=True, help="track file to write (.npz: landmarks (T,68,3) float32, fps)")
    predict.add_argument("--transcript", type=Path, metavar="TEXT_FILE", help="the words spoken (UTF-8 text, or .srt/.vtt subtitles: each cue aligned within its own times; English): the jaw and lips follow their phones, aligned to the audio")
    predict.add_argument("--recognise", action="store_true", help="no transcript? recognise the words spoken (English) and move the jaw and lips from their phones as --transcript does")
    predict.add_argument("--fps", type=float, default=25.0, help="frames per second of the track (default 25)")
    predict.add_argument("--seed", type=int, default=0, help="seed for blinks and idle motion (default 0)")
    predict.add_argument("-f", "--force", action="store_true", help="overwrite an existing track")

    train = commands.add_parser(
        "train",
        help="rebuild the lip-sync network: make the TTS corpus, label it, train, export ONNX (needs the train extra)",
        description="Rebuild the shipped lip-sync models from scratch: synthesise and augment a speech corpus with local "
        "TTS voices, align it with pocketsphinx and compute articulation targets, train the network twice (the live "
        "model hears 60 ms ahead, the offline one 300 ms; files use the two averaged), train each a voice detector "
        "against made-up music and noise (played by sampled instruments where fluidsynth and a GM soundfont are "
        "installed: apt-get install fluidsynth fluid-soundfont-gm), export ONNX. Every stage resumes where it stopped.",
    )
    train.add_argument("--corpus", type=Path, default=Path.home() / ".cache" / "puppet" / "corpus", help="corpus folder (default ~/.cache/puppet/corpus)")
    train.add_argument("--hours", type=float, default=6.0, help="hours of speech in the corpus (default 6)")
    train.add_argument("--out", type=Path, default=Path("runs") / "landmarks", help="checkpoints, logs and ONNX models, in OUT/streaming and OUT/offline (default runs/landmarks)")
    train.add_argument("--model", choices=["both", "streaming", "offline"], default="both", help="which model to train: the live one (hears 60 ms ahead), the offline one (300 ms), or both (default; files use both)")
    train.add_argument("--steps", type=int, help="training steps (default: the training config's)")
    train.add_argument("--seed", type=int, default=0, help="corpus seed (default 0)")
    train.add_argument("--install", action="store_true", help="copy the exported models into this install's assets/models")

    evaluate = commands.add_parser(
        "eval",
        help="score lip sync (MakeItTalk's D-LL, D-VL, D-A, D-L, D-V, D-Rot) against baselines",
        description="Score the lip-sync network beside the loudness baseline and a static face, on held-out synthetic "
        "voices of a corpus and on real talking videos (landmarks tracked with puppet's own detector).",
    )
    evaluate.add_argument("--corpus", type=Path, help="corpus folder: its held-out speakers are scored")
    evaluate.add_argument("--videos", type=Path, help="folder of talking-face videos with speech (.mp4, .mov, .mkv)")
    evaluate.add_argument("--speech", type=Path, help="folder of real recordings with transcripts (NAME.wav + NAME.txt): what the mouth does on p/b/m, vowels, oo/ee and silence")
    evaluate.add_argument("--sounds", type=Path, metavar="DIR", help="folder of audio with nobody speaking (music, noise, typing): how far the mouth opens on it")
    evaluate.add_argument("--labels", type=int, metavar="N", help="score the training labels themselves: N sentences by festival, the aligner's phones against festival's own times (needs festival)")
    evaluate.add_argument("--json", type=Path, help="also write the scores here")
    evaluate.add_argument("--plots", type=Path, metavar="DIR", help="also draw each video's lip opening over time, real against each source, as DIR/NAME.png")
    evaluate.add_argument("-f", "--force", action="store_true", help="overwrite an existing --json file or --plots folder")
    evaluate.add_argument("--limit", type=int, default=200, help="held-out utterances scored at most (default 200)")

    bench = commands.add_parser("bench", help="measure rendering and export speed on this machine")
    bench.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    bench.add_argument("--seconds", type=float, default=3.0, help="time spent on each render measurement (default 3)")
    bench.add_argument("--clip", type=float, default=30.0, help="length of the export clip in seconds (default 30)")
    bench.add_argument("--soak", type=float, metavar="MINUTES", help="instead: run the live loop this long and report its memory (flat is good) and latency")
    return parser


def _add_rigging_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--landmarks", type=Path, help="68-point landmark file: text (68 rows 'x y [z]'), .json or .npy, image pixels")
    group.add_argument("--points", nargs=5, metavar="X,Y", help=POINTS_HELP + " (try this on cartoons no detector understands)")


def run(args: argparse.Namespace) -> int:
    from puppet import bundle

    points = None
    if getattr(args, "points", None):
        from puppet.template import parse_points

        points = parse_points(args.points)

    if args.command == "rig":
        try:
            puppet = bundle.load(args.image, args.landmarks, points)
        except NoFaceError:
            if not args.edit:
                raise
            puppet = bundle.load_centred(args.image)
            print("no face found: starting from a face placed in the middle; drag its points onto the face")
        output = args.output or (args.image if args.image.is_dir() else args.image.with_suffix(".puppet"))
        if args.edit:
            from puppet.editor import edit

            folder = edit(puppet, output, args.force or output == args.image)
            print(f"saved {folder}" if folder else "closed without saving")
            return 0
        folder = bundle.save(puppet, output, args.force)
        print(f"rigged {args.image} -> {folder}  (check {folder / bundle.PREVIEW_FILE}; adjust with: puppet rig {folder} --edit; "
              f"render with: puppet render {folder} SPEECH.wav -o out.mp4)")
        return 0

    if args.command == "live":
        return _live(args, points)
    if args.command == "predict":
        return _predict(args)
    if args.command == "train":
        return _train(args)
    if args.command == "eval":
        return _evaluate(args)
    if args.command == "bench":
        from puppet.bench import main as bench_main

        return bench_main(args.json, args.seconds, args.clip, args.soak)

    from puppet import audio, export, lipsync, video

    if args.demo:
        if args.input is not None:
            raise PuppetError("--demo uses the bundled character and speech: give no INPUT or AUDIO with it")
        image, landmark_file, speech = bundle.demo_files()
        puppet = bundle.load(image, landmark_file)
        audio_path = speech
    else:
        if args.input is None:
            raise PuppetError("give a portrait (image or bundle) and an audio file, or --demo")
        puppet = bundle.load(args.input, args.landmarks, points)
        audio_path = args.audio
        if audio_path is None and args.motion in (None,) + video.MOTION_SOURCES:
            raise PuppetError("give an audio file after the portrait (or --motion TRACK.npz)")
    motion = args.motion or video.default_motion()
    if args.transcript and args.recognise:
        raise PuppetError("give --transcript or --recognise, not both")
    transcript = lipsync.read_transcript(args.transcript) if args.transcript else None
    options = video.VideoOptions(fps=args.fps, background=args.background, samples=args.msaa, motion=motion, expression=args.expression,
                                 transcript=transcript, recognise=args.recognise)
    if args.size is not None:
        size = args.size if isinstance(args.size, tuple) else video.output_size(puppet.rig.image_size, args.size)
        options = replace(options, size=size)
    options = replace(options, life=replace(options.life, seed=args.seed))
    if (transcript is not None or args.recognise) and motion == "learned" and not args.quiet:
        export.check_output(args.output, args.force)  # refuse a bad output or audio before announcing the wait
        audio.probe(audio_path)
        _say_aligning(args.recognise)
    output = video.render(puppet, audio_path, args.output, options, args.force, args.landmarks_out, progress=not args.quiet)
    print(f"wrote {output}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return run(args)
    except PuppetError as error:
        print(f"puppet: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("puppet: interrupted", file=sys.stderr)
        return 130
    except Exception as error:  # a bug, not bad input: still one line unless asked for more
        if os.environ.get("PUPPET_DEBUG"):
            raise
        print(f"puppet: internal error: {type(error).__name__}: {error} (set PUPPET_DEBUG=1 for details)", file=sys.stderr)
        return 1


def _say_aligning(recognise: bool = False) -> None:
    """What the wait before the first frame is, when words are recognised or a transcript is aligned (no bar can show its progress)."""
    if recognise:
        print("recognising the words and aligning them to the audio (about 25 s a minute of speech)…", file=sys.stderr, flush=True)
    else:
        print("aligning the transcript to the audio (about 6 s a minute of speech, more where it does not fit)…", file=sys.stderr, flush=True)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """PuppetWarnings as one line, like errors; other warnings as Python shows them."""
    if issubclass(category, PuppetWarning):
        print(f"puppet: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=file or sys.stderr, end="")


def _predict(args: argparse.Namespace) -> int:
    from puppet import audio, lipsync, track
    from puppet.landmarks import load, with_depth
    from puppet.life import LifeOptions, life_motion
    from puppet.loudness import frame_count
    from puppet.pose import posed_landmarks
    from puppet.video import check_track_output

    if args.transcript and args.recognise:
        raise PuppetError("give --transcript or --recognise, not both")
    output = check_track_output(args.output, args.force)
    rest = with_depth(load(args.face) if args.face else canonical_face_pixels())
    transcript = lipsync.read_transcript(args.transcript) if args.transcript else None
    samples = audio.load(args.audio)
    audio.check_audible(samples, str(args.audio))
    frames = frame_count(len(samples), audio.ANALYSIS_RATE, args.fps)
    if transcript is not None or args.recognise:
        _say_aligning(args.recognise)
    motion = lipsync.learned_motion(samples, rest, args.fps, frames, transcript=transcript, recognise=args.recognise)
    motion = motion + life_motion(frames, args.fps, rest, LifeOptions(seed=args.seed))
    track.write(output, posed_landmarks(rest, motion), args.fps)
    print(f"wrote {output} ({frames} frames at {args.fps:g} fps)")
    return 0


def canonical_face_pixels():
    """(68, 2) the canonical face drawn in a 512×512 frame: eyes 100 px apart."""
    from puppet.template import MEAN_FACE

    return MEAN_FACE * 100.0 + (256.0, 220.0)


def _train(args: argparse.Namespace) -> int:
    try:
        import onnx  # noqa: F401  torch.onnx.export writes through it: missing, it would fail only after hours of training

        from puppet import corpus, labels, train
    except ImportError as error:
        raise PuppetError(f"training needs the train extra ({error.name} is missing): pip install 'puppet[train]'") from None
    import shutil
    from dataclasses import replace as change

    corpus.build(args.corpus, corpus.CorpusOptions(hours=args.hours, seed=args.seed))
    labels.label(args.corpus)
    from puppet.predictor import default_model

    for kind in ["streaming", "offline"] if args.model == "both" else [args.model]:
        config = train.recipe(kind, corpus=str(args.corpus), out=str(args.out / kind))
        if args.steps:
            config = change(config, steps=args.steps)
        print(f"training the {kind} model")
        train.train(config)
        model = args.out / kind / train.ONNX_FILE
        if args.install:
            shutil.copyfile(model, default_model(kind))
            print(f"installed {model} as {default_model(kind)}")
        print(f"trained: {model}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    import json

    from puppet.evaluate import (
        format_table,
        score_corpus,
        score_labels,
        score_phones,
        score_sounds,
        score_videos,
    )

    if all(value is None for value in (args.corpus, args.videos, args.speech, args.sounds, args.labels)):
        raise PuppetError("give --corpus DIR (held-out synthetic voices), --videos DIR (real talking videos), --speech DIR (recordings "
                          "with transcripts), --sounds DIR (audio with nobody speaking) and/or --labels N")
    if args.labels is not None and args.labels < 1:
        raise PuppetError("--labels needs a number of sentences, 1 or more")
    if args.json and args.json.exists() and not args.force:
        raise PuppetError(f"{args.json} exists; use --force to overwrite")
    if args.plots and args.plots.is_dir() and any(args.plots.iterdir()) and not args.force:
        raise PuppetError(f"{args.plots} is not empty; use --force to draw over its pictures")
    if args.plots:
        try:
            args.plots.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise PuppetError(f"cannot make the --plots folder {args.plots}: {error.strerror}") from None
    results = {}
    if args.corpus is not None:
        results["synthetic"] = score_corpus(args.corpus, args.limit)
        print(format_table(f"held-out synthetic voices ({args.corpus})", results["synthetic"]))
    if args.videos is not None:
        results["video"] = score_videos(args.videos, plots=args.plots)
        print(format_table(f"real talking videos ({args.videos})", results["video"]))
    if args.speech is not None:
        results["speech"] = score_phones(args.speech)
        print(format_table(f"real recordings, mouth per sound ({args.speech})", results["speech"]))
    if args.sounds is not None:
        results["sounds"] = score_sounds(args.sounds)
        print(format_table(f"nobody speaking, lip opening ({args.sounds})", results["sounds"]))
    if args.labels is not None:
        results["labels"] = score_labels(args.labels)
        print(format_table(f"training labels: aligned phones against festival's own ({args.labels} sentences)", results["labels"]["motion"]))
        print("phone boundaries: median {median_ms:.0f} ms, 90th percentile {p90_ms:.0f} ms, {within_20ms:.0%} within 20 ms".format(**results["labels"]["boundaries"]))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


def _live(args: argparse.Namespace, points) -> int:
    """`puppet live`: everything checked before the window opens, then the loop."""
    from puppet import bundle, capture, live, settings
    from puppet.video import output_size

    if args.list_devices:
        print(capture.list_devices())
        return 0
    if args.demo == (args.input is not None):
        raise PuppetError("give a portrait (image or bundle) or --demo")
    if args.stats is not None:
        if args.stats.exists() and not args.force:
            raise PuppetError(f"{args.stats} exists; use --force to overwrite")
        if not args.stats.parent.is_dir():
            raise PuppetError(f"output folder does not exist: {args.stats.parent}")
    if args.audio is None and (args.no_playback or args.loop):
        raise PuppetError("--no-playback and --loop are for --audio FILE")
    if args.demo:
        image, landmark_file, _ = bundle.demo_files()
        puppet, source_path = bundle.load(image, landmark_file), None
    else:
        puppet, source_path = bundle.load(args.input, args.landmarks, points), args.input
    path = settings.settings_path(source_path, puppet.name)
    chosen = settings.load(path)
    overrides = {"expression": args.expression, "sensitivity_db": args.sensitivity, "gate_db": args.gate, "blink_rate": args.blink_rate,
                 "blink_randomness": args.blink_randomness}
    chosen = replace(chosen, **{k: v for k, v in overrides.items() if v is not None})
    chosen = replace(chosen, push_to_talk=chosen.push_to_talk or args.push_to_talk, show_stats=chosen.show_stats or args.show_stats).clamped()

    size = args.size if isinstance(args.size, tuple) else output_size(puppet.rig.image_size, args.size or 720)
    options = live.LiveOptions(size=size, fps=args.fps, samples=args.msaa, duration=args.duration, seed=args.seed)
    if args.background is not None:
        options = replace(options, background=args.background)
        if args.background.opaque:
            options = replace(options, key=args.background.rgba[:3])
    if args.audio is not None:
        source = capture.FilePlayer(args.audio, playback=not args.no_playback, loop=args.loop)
    else:
        source = capture.Microphone(args.device)
    camera = None
    if args.virtual_camera:
        from puppet.camera import VirtualCamera

        camera = VirtualCamera(size, args.camera_fps, tuple(round(c * 255) for c in options.key), args.camera_device)
    display = None
    try:
        display = _open_display(args.no_window, puppet.name, size, options)
        if camera is not None:
            print(f"sending frames to the virtual camera: {camera.name}")
        stats = live.run(puppet, source, display, options, chosen, camera, path)
    finally:
        if display is not None:
            display.close()
        if camera is not None:
            camera.close()
    if args.stats is not None:
        summary = live.write_stats(args.stats, stats, {"size": list(size), "source": source.name, "window": not args.no_window})
        print(f"wrote {args.stats}: {summary['fps']} fps, latency p50 {summary['latency_ms_p50']} ms, p95 {summary['latency_ms_p95']} ms, {summary['dropped_frames']} dropped frames")
    return 0


def _open_display(offscreen: bool, name: str, size: tuple[int, int], options):
    """The live loop's display: a window, or an offscreen canvas on a headless EGL context."""
    from puppet.window import Offscreen, Window

    if offscreen:
        from puppet.renderer import headless_context

        return Offscreen(headless_context(), size, options.samples, owns_context=True)
    return Window(f"puppet live: {name}", size, transparent=not options.background.opaque)
