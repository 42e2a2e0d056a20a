"""Export: rendered frames to an H.264 video with the speech muxed in, or to a folder of PNGs.

Every writer takes frames as (H, W, 4) uint8 RGBA, straight (not premultiplied) alpha, rows top
to bottom, and is a context manager with `send(frame)` / `close()`; `open_output` picks the writer
from the path, in one place. Output is atomic: a writer fills a hidden sibling
(`.NAME.partial-XXXXXXXX` beside the target) and a clean close renames it into place; an exception
in the `with` block (KeyboardInterrupt included) or a failed close removes it, so a half-written
file never sits where the user expects a finished one.

The video writer encodes H.264 on a background thread fed by a small bounded queue: libx264,
swscale and the muxer release the GIL, so encoding overlaps the caller's rendering while memory
stays flat. The audio is streamed from its file and encoded to AAC on a second thread, a bounded
few packets ahead; after video frame i, the AAC packets up to that frame's end time, (i + 1) / fps,
are muxed, so the two streams interleave as the frames arrive.
"""
import contextlib
import math
import os
import queue
import re
import secrets
import shutil
import threading
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
from av.video.reformatter import ColorRange

from puppet.audio import AudioInfo, iter_resampled, probe
from puppet.errors import PuppetError, reason

VIDEO_MUXERS = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}  # output suffix -> FFmpeg muxer
FAST_START_MUXERS = {"mp4", "mov"}  # index moved to the front so players start before the download ends
X264_PRESETS = (
    "ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow",
)
# 512×512 flat-shaded 25 fps frames on 2 cores: ~38× real time (~24× with stereo AAC), ~250 kbit/s;
# "veryfast" halves the size but runs ~23× (~19× with AAC), too close to the 20× target.
DEFAULT_PRESET = "superfast"
DEFAULT_CRF = 20  # x264 constant quality (0 lossless … 51 worst): 54 dB PSNR on flat-shaded frames
# x264 threads: half the cores, leaving the rest to the renderer that feeds it (on 2 cores
# one encoder thread beats x264's default of 3 by ~10 % end to end).
ENCODER_THREADS = max(1, (os.cpu_count() or 2) // 2)
AAC_RATES = (16000, 22050, 24000, 32000, 44100, 48000)  # Hz: common rates the audio keeps as they are
AAC_FALLBACK_RATE = 48000  # Hz: audio at any other rate is resampled to this
AAC_BIT_RATE_PER_CHANNEL = 64_000  # bit/s: transparent for speech
QUEUE_FRAMES = 6  # frames waiting for the encoder thread: 6 × 384 KB of YUV at 512², memory stays flat
AUDIO_AHEAD_PACKETS = 64  # AAC packets (1024 samples each) encoded ahead of the video: ~1.4 s at 48 kHz
AVCOL_SPC_SMPTE170M = 6  # FFmpeg's AVColorSpace for the BT.601 matrix that cv2's RGB→I420 uses
FRAME_NAME = "frame_{:06d}.png"  # frame_000000.png, frame_000001.png, …
FRAME_NAME_PATTERN = re.compile(r"frame_\d{6,}\.png")


def check_output(path, force: bool) -> Path:
    """Validate an output path before any heavy work; returns it as a Path.

    `.mp4`, `.mov`, `.mkv` give an H.264 video; a path without a suffix gives a folder of PNG
    frames. The parent folder must exist. An existing target is refused unless `force`, and even
    then a folder is only replaced if it holds nothing but frame PNGs.
    """
    path = Path(path)
    if path.suffix and path.suffix.lower() not in VIDEO_MUXERS:
        raise PuppetError(
            f"unsupported output type '{path.suffix}' for {path}: use .mp4, .mov or .mkv for a video, "
            "or a name without a suffix for a folder of PNG frames"
        )
    if not path.parent.is_dir():
        raise PuppetError(f"output folder does not exist: {path.parent}")
    if path.exists() or path.is_symlink():
        if not force:
            raise PuppetError(f"{path} exists; use --force to overwrite")
        _check_replaceable(path)
    return path


def open_output(path, size: tuple[int, int], fps: float, audio_path=None, force: bool = False, **opts):
    """The writer for `path`: VideoWriter for a video suffix, else FrameFolderWriter.

    size: (W, H) pixels of the frames to come. A folder of frames has no sound, so `audio_path`
    and the encoder options in `opts` only apply to videos.
    """
    if Path(path).suffix:
        return VideoWriter(path, size, fps, audio_path=audio_path, force=force, **opts)
    return FrameFolderWriter(path, force=force)


class _AtomicOutput:
    """Writes into a hidden sibling of the target; a clean close renames it into place."""

    def __init__(self, path, force: bool):
        self.path = check_output(path, force)
        self.force = force
        self._partial = self.path.with_name(f".{self.path.name}.partial-{secrets.token_hex(4)}")
        self._frames = 0  # sent so far
        self._closed = False

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def close(self) -> None:
        """Finish writing and move the output into place; if that fails, nothing is left behind."""
        if self._closed:
            return
        self._closed = True
        try:
            if not self._frames:
                raise PuppetError(f"no frames were rendered; {self.path} was not written")
            self._finish()
            _move_into_place(self._partial, self.path, self.force)
        except (av.FFmpegError, OSError, cv2.error) as e:
            self._discard()
            raise PuppetError(f"could not write {self.path}: {reason(e)}") from e
        except BaseException:
            self._discard()
            raise

    def abort(self) -> None:
        """Stop writing and remove the partial output; the target is left as it was."""
        if not self._closed:
            self._closed = True
            self._discard()

    def _discard(self) -> None:
        try:
            self._abandon()
        finally:
            _remove(self._partial)

    def _check_frame(self, frame: np.ndarray, size: tuple[int, int] | None) -> None:
        if self._closed:
            raise ValueError(f"send() after close() of {self.path}")
        shape = (size[1], size[0], 4) if size else (*frame.shape[:2], 4)
        if frame.shape != shape or frame.dtype != np.uint8:
            raise ValueError(f"expected a {shape} uint8 RGBA frame, got {frame.shape} {frame.dtype}")

    def _finish(self) -> None:
        """Complete the partial output (flush, write trailers)."""

    def _abandon(self) -> None:
        """Release resources without finishing; must not raise."""


class VideoWriter(_AtomicOutput):
    """H.264 (libx264, yuv420p, BT.601 limited range) video, with the audio of `audio_path` as AAC.

    The audio keeps its rate when it is one of AAC_RATES (else it becomes 48 kHz); mono stays mono,
    anything wider becomes stereo.

    size: (W, H) of the frames; H.264 4:2:0 needs both even, so the caller pads or crops.
    fps:  frames per second (fractional rates such as 30000/1001 are kept exact to 1e-6).
    Alpha is dropped: the RGB of transparent pixels shows as is, so render onto an opaque background.
    Frames are copied on `send`, so the caller may reuse its array. The video's duration equals the
    audio's within one frame when the caller sends ceil(audio seconds × fps) frames; audio left
    over at close is still written.
    """

    def __init__(self, path, size: tuple[int, int], fps: float, audio_path=None,
                 crf: int = DEFAULT_CRF, preset: str = DEFAULT_PRESET, force: bool = False):
        width, height = size
        if width <= 0 or height <= 0 or width % 2 or height % 2:
            raise PuppetError(f"H.264 video needs an even, positive width and height; got {width}×{height}")
        if preset not in X264_PRESETS:
            raise PuppetError(f"unknown x264 preset '{preset}': use one of {', '.join(X264_PRESETS)}")
        if not 0 <= crf <= 51:
            raise PuppetError(f"crf must be 0 (lossless) … 51 (worst), got {crf}")
        if not (fps > 0 and math.isfinite(fps)):
            raise PuppetError(f"fps must be a positive number, got {fps}")
        super().__init__(path, force)
        # Bad audio fails here, before any file exists.
        audio = probe(audio_path) if audio_path is not None else None
        self._size = (width, height)
        self._fps = Fraction(fps).limit_denominator(1_000_000)
        muxer = VIDEO_MUXERS[self.path.suffix.lower()]
        try:
            self._container = av.open(
                str(self._partial), "w", format=muxer,
                container_options={"movflags": "+faststart"} if muxer in FAST_START_MUXERS else {},
            )
        except (av.FFmpegError, OSError) as e:
            raise PuppetError(f"cannot create {self.path}: {reason(e)}") from None
        try:
            self._add_streams(crf, preset, audio)
            self._container.start_encoding()  # opens the codecs and the file here, not in a thread
            self._audio = _AudioPackets(self._audio_stream, audio_path) if audio is not None else None
        except BaseException as e:
            self._container.close()
            _remove(self._partial)
            if isinstance(e, (av.FFmpegError, OSError)):
                raise PuppetError(f"cannot create {self.path}: {reason(e)}") from None
            raise
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_FRAMES)
        self._error: BaseException | None = None
        self._aborting = False
        self._thread = threading.Thread(target=self._run, name="puppet-encoder", daemon=True)
        self._thread.start()

    def _add_streams(self, crf: int, preset: str, audio: AudioInfo | None) -> None:
        width, height = self._size
        self._video = self._container.add_stream(
            "libx264", rate=self._fps, width=width, height=height, pix_fmt="yuv420p",
            options={"crf": str(crf), "preset": preset, "threads": str(ENCODER_THREADS)},
        )
        self._video.codec_context.colorspace = AVCOL_SPC_SMPTE170M
        self._video.codec_context.color_range = ColorRange.MPEG
        self._audio_stream = None
        if audio is not None:
            channels = min(audio.channels, 2)
            rate = audio.sample_rate if audio.sample_rate in AAC_RATES else AAC_FALLBACK_RATE
            layout = "mono" if channels == 1 else "stereo"
            self._audio_stream = self._container.add_stream("aac", rate=rate, layout=layout)
            self._audio_stream.bit_rate = AAC_BIT_RATE_PER_CHANNEL * channels

    def send(self, frame: np.ndarray) -> None:
        """Queue one (H, W, 4) uint8 RGBA frame; blocks while the encoder is QUEUE_FRAMES behind."""
        self._check_frame(frame, self._size)
        self._raise_encoder_error()
        yuv = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGBA2YUV_I420)  # (H·3/2, W) uint8
        video_frame = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        video_frame.pts = self._frames
        self._frames += 1
        self._queue.put(video_frame)

    def _run(self) -> None:
        """Encoder thread: encode and mux queued frames until the None sentinel."""
        while (frame := self._queue.get()) is not None:
            if self._error is not None or self._aborting:
                continue  # keep draining so send() and close() never block on a full queue
            try:
                self._mux(self._video.encode(frame))
                if self._audio is not None:
                    self._mux(self._audio.until((frame.pts + 1) / self._fps))
            except (av.FFmpegError, OSError) as e:
                self._error = PuppetError(f"could not write {self.path}: {reason(e)}")
                self._error.__cause__ = e
            except BaseException as e:  # noqa: BLE001 - re-raised in the caller's thread by send()/close()
                self._error = e

    def _mux(self, packets) -> None:
        for packet in packets:
            self._container.mux(packet)

    def _raise_encoder_error(self) -> None:
        if self._error is not None:
            raise self._error

    def _stop_thread(self) -> None:
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()

    def _finish(self) -> None:
        self._stop_thread()
        self._raise_encoder_error()
        self._mux(self._video.encode(None))
        if self._audio is not None:
            self._mux(self._audio.until(None))
        self._container.close()

    def _abandon(self) -> None:
        self._aborting = True
        if self._audio is not None:
            self._audio.stop()  # first: the encoder thread may be waiting for its packets
        self._stop_thread()
        try:
            self._container.close()
        except (av.FFmpegError, OSError):
            pass  # the partial file is removed next; its trailer does not matter


class _AudioPackets:
    """AAC packets of an audio file, encoded on their own thread so AAC overlaps the H.264 work.

    The thread streams the file (`iter_resampled`) and stays at most AUDIO_AHEAD_PACKETS ahead of
    the consumer, so memory stays flat however long the audio is.
    """

    def __init__(self, stream: av.audio.AudioStream, audio_path):
        self._stream = stream
        self._frames = iter_resampled(audio_path, stream.rate, stream.layout.name)
        self._queue: queue.Queue = queue.Queue(maxsize=AUDIO_AHEAD_PACKETS)
        self._pending: av.Packet | None = None  # taken from the queue, not yet due
        self._done = False
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="puppet-audio-encoder", daemon=True)
        self._thread.start()

    def until(self, seconds) -> Iterator[av.Packet]:
        """The packets that start before `seconds` (None: all the rest); re-raises encoding errors."""
        while not self._done:
            if self._pending is None:
                item = self._queue.get()
                if item is _END:
                    self._done = True
                    return
                if isinstance(item, BaseException):
                    self._done = True
                    raise item
                self._pending = item
            if seconds is not None and self._pending.pts * self._pending.time_base >= seconds:
                return
            yield self._pending
            self._pending = None

    def stop(self) -> None:
        """End the thread without finishing, and wake a consumer waiting in `until`."""
        self._stopping = True
        self._thread.join()
        with contextlib.suppress(queue.Empty):
            while True:
                self._queue.get_nowait()
        self._queue.put_nowait(_END)

    def _run(self) -> None:
        rate, samples = self._stream.rate, 0
        try:
            for frame in self._frames:
                frame.pts, frame.time_base = samples, Fraction(1, rate)
                samples += frame.samples
                for packet in self._stream.encode(frame):
                    self._put(packet)
                if self._stopping:
                    return
            for packet in self._stream.encode(None):
                self._put(packet)
            self._put(_END)
        except BaseException as e:  # noqa: BLE001 - raised again in the consumer's thread by `until`
            self._put(e)
        finally:
            self._frames.close()

    def _put(self, item) -> None:
        while not self._stopping:
            with contextlib.suppress(queue.Full):
                self._queue.put(item, timeout=0.05)
                return


_END = object()  # marks the last of the audio packets


class FrameFolderWriter(_AtomicOutput):
    """A folder of RGBA PNGs, frame_000000.png, frame_000001.png, …, alpha kept exactly."""

    def __init__(self, path, force: bool = False):
        super().__init__(path, force)
        try:
            self._partial.mkdir()
        except OSError as e:
            raise PuppetError(f"cannot create {self.path}: {reason(e)}") from None

    def send(self, frame: np.ndarray) -> None:
        """Write one (H, W, 4) uint8 RGBA frame as the next PNG."""
        self._check_frame(frame, None)
        file = self._partial / FRAME_NAME.format(self._frames)
        try:
            bgra = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGBA2BGRA)
            written = cv2.imwrite(str(file), bgra)
        except cv2.error:
            written = False
        if not written:
            raise PuppetError(f"could not write frame {self._frames} of {self.path}")
        self._frames += 1


def _check_replaceable(path: Path) -> None:
    """With --force, refuse targets whose loss would hurt: folders holding anything but our frames."""
    if not path.is_dir():
        return
    if path.suffix:
        raise PuppetError(f"{path} is a folder; refusing to replace it with a video")
    if any(not FRAME_NAME_PATTERN.fullmatch(entry.name) for entry in path.iterdir()):
        raise PuppetError(f"{path} is a folder with other files than frame PNGs; refusing to replace it")


def _move_into_place(partial: Path, target: Path, force: bool) -> None:
    """Rename `partial` to `target`, replacing an existing target only when `force`."""
    if target.exists() or target.is_symlink():
        if not force:  # it appeared while we were rendering
            raise PuppetError(f"{target} exists; use --force to overwrite")
        _check_replaceable(target)
        if partial.is_dir() or (target.is_dir() and not target.is_symlink()):
            # A folder cannot atomically replace (or be replaced by) anything: swap, then delete.
            old = target.with_name(f".{target.name}.old-{secrets.token_hex(4)}")
            target.rename(old)
            try:
                partial.rename(target)
            except BaseException:
                old.rename(target)
                raise
            _remove(old)
            return
    os.replace(partial, target)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink(missing_ok=True)
