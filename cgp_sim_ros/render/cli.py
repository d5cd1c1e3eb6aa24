"""``cgp-sim-render BAG -o OUT``: render the markers of a bag to a video, a GIF or pictures — no ROS, no display.

    cgp-sim-render bags/run1 -o run1.mp4                      # the whole bag, 30 fps, 960x540
    cgp-sim-render bags/run1 -o fall.gif --from 0 --to 3 --fps 15 --size 480x270
    cgp-sim-render run1_0.mcap -o still.png --from 2.5        # one picture, at 2.5 s
    cgp-sim-render bags/run1 -o frames/f_%04d.png --to 1      # one PNG per frame
    cgp-sim-render bags/run1 -o top.mp4 --camera 0,-0.1,40:0,0,0   # from 40 m above, looking down

BAG is a rosbag2 directory (as ``cgp-sim --bag`` records) or one ``.mcap`` file.  The output's suffix picks the
format: ``.mp4`` (H.264 through the ffmpeg that the ``imageio-ffmpeg`` wheel ships), ``.gif`` (Pillow, one
palette for the whole animation, looping), ``.png`` (one picture at ``--from``; a name with a printf pattern
such as ``%04d`` writes one numbered picture per frame).

The bodies and static meshes, which the node sends on the latched ``~/static_markers`` when they change (not on
every tick; the bodies in their own TF frames, placed by the bag's ``/tf`` and ``/tf_static`` as a viewer places
them), are drawn with the ``~/markers`` of the same instant (``--topic T`` draws ``T`` and, beside a ``.../markers``
topic, its ``.../static_markers``).

Time: ``--from`` / ``--to`` are seconds from the first marker message of the bag (for a cgp-sim bag that is the
first tick, in simulation time).  Frame k shows the markers as they were at ``from + k · speed / fps`` — the latest
message at or before that time, as a viewer replaying the bag would show them (so ``markers_every`` > 1 and
DELETEALL after a ``~/reset`` are rendered as published).

Camera (``--camera EX,EY,EZ[:TX,TY,TZ]``, metres, frame ``world``, z up): the eye, and the point it looks at
(default: the centre of what is drawn).  Without ``--camera`` the camera looks from the south-east, 25° above
the horizon (``--azimuth``, ``--elevation``), at the distance where everything drawn at five instants across the
rendered time fits the picture (the ground is drawn but not fitted).  The camera does not move.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import time
from pathlib import Path

import numpy as np

from cgp_core.user_input import UserInputError, regular_file

from ..progress import ProgressLine, bar, format_duration
from ..wire import cdr
from .bagread import BagError, MarkerStream, open_marker_stream
from .primitives import MarkerSet, Transforms, extent_points, primitives
from .raster import Camera, Rasterizer

FORMATS = (".mp4", ".gif", ".png")
#: instants sampled across the rendered span for the default camera framing
FRAMING_SAMPLES = 5
#: ... each drawn from the markers of this span before it (the node publishes every marker each tick, or
#: every ``markers_every`` ticks)
FRAMING_LOOKBACK_NS = 2_000_000_000
#: H.264 quality (x264's constant rate factor: 0 lossless, 23 its default, 18 "visually lossless")
MP4_CRF = 20
#: colours of the GIF palette (one palette for every frame: no flicker, smaller files)
GIF_COLORS = 128
_NS = 1_000_000_000
_PRINTF = re.compile(r"%0?\d*d")


class RenderError(ValueError):
    """Bad arguments or input, with the reason (the command exits 2)."""


def _vector(text: str, what: str) -> np.ndarray:
    parts = text.split(",")
    try:
        values = np.array([float(p) for p in parts])
    except ValueError:
        raise RenderError(f"--camera: {what} {text!r} is not three numbers x,y,z") from None
    if values.shape != (3,) or not np.all(np.isfinite(values)):
        raise RenderError(f"--camera: {what} {text!r} is not three finite numbers x,y,z")
    return values


def parse_camera(text: str) -> tuple[np.ndarray, np.ndarray | None]:
    """``EX,EY,EZ`` or ``EX,EY,EZ:TX,TY,TZ`` → (eye, target or None)."""
    eye_text, _, target_text = text.replace(" ", "").partition(":")
    eye = _vector(eye_text, "eye")
    target = _vector(target_text, "target") if target_text else None
    if target is not None and np.linalg.norm(target - eye) < 1e-9:
        raise RenderError("--camera: eye and target are the same point")
    return eye, target


def parse_size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 960x540, got {text!r}")
    width, height = int(match.group(1)), int(match.group(2))
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise argparse.ArgumentTypeError(f"width and height must be within 16..8192, got {width}x{height}")
    return width, height


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cgp-sim-render", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Render the markers of a cgp-sim bag (a rosbag2 directory or an .mcap file) to an MP4 video, "
                    "a GIF or PNG pictures, without ROS and without a display.",
        epilog="--camera syntax: EX,EY,EZ[:TX,TY,TZ] in metres (frame world, z up): the eye, then the point it "
               "looks at (default: the centre of the scene), e.g. --camera 12,-16,9 or --camera 0,-0.1,40:0,0,0 "
               "(from 40 m above). Times are seconds from the bag's first marker message.")
    parser.add_argument("bag", help="rosbag2 directory or .mcap file")
    parser.add_argument("-o", "--output", required=True,
                        help="output file: .mp4, .gif or .png (one picture; a %%04d pattern writes every frame)")
    parser.add_argument("--from", dest="start", type=float, default=0.0, metavar="S",
                        help="first frame's time [s from the bag's start] (default 0)")
    parser.add_argument("--to", dest="end", type=float, default=None, metavar="S",
                        help="last time to render [s] (default: the end of the bag)")
    parser.add_argument("--fps", type=float, default=30.0, help="frames per second of the output (default 30)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="simulated seconds per second of video (default 1: real time)")
    parser.add_argument("--size", type=parse_size, default=(960, 540), metavar="WxH",
                        help="picture size in pixels (default 960x540)")
    parser.add_argument("--camera", default=None, metavar="EX,EY,EZ[:TX,TY,TZ]",
                        help="camera eye (and target); default: framed from the scene's extent")
    parser.add_argument("--azimuth", type=float, default=-60.0,
                        help="default camera: direction it looks from, degrees from +x counter-clockwise (-60)")
    parser.add_argument("--elevation", type=float, default=25.0,
                        help="default camera: degrees above the horizon (25)")
    parser.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees (default 40)")
    parser.add_argument("--topic", default=None,
                        help="MarkerArray topic (default: /cgp_sim/markers, or the bag's only MarkerArray topic)")
    parser.add_argument("--supersample", type=int, default=2, metavar="N",
                        help="anti-aliasing: render N x N samples per pixel (default 2; 1 = off, faster)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    return parser


# ------------------------------------------------------------------------------------------------- frames
def frame_times(stream: MarkerStream, start_s: float, end_s: float | None, fps: float, speed: float,
                still: bool) -> np.ndarray:
    """Log times [ns] of the frames to render."""
    span_s = (stream.end_ns - stream.start_ns) / _NS
    end_s = span_s if end_s is None else min(end_s, span_s)
    if start_s < 0 or start_s > span_s:
        raise RenderError(f"--from {start_s:g}: the bag spans 0 to {span_s:.3f} s")
    if end_s < start_s:
        raise RenderError(f"--to {end_s:g} is before --from {start_s:g}")
    if still:
        return np.array([stream.start_ns + round(start_s * _NS)], dtype=np.int64)
    step = speed / fps
    count = int(math.floor((end_s - start_s) / step + 1e-9)) + 1
    return stream.start_ns + np.round((start_s + step * np.arange(count)) * _NS).astype(np.int64)


class Undecodable:
    """Marker messages that are not a MarkerArray's CDR (a damaged or foreign bag): skipped, counted, the first
    reason kept for the summary line."""

    def __init__(self) -> None:
        self.count = 0
        self.decoded = 0
        self.first = ""

    def decode(self, data: bytes):
        try:
            markers = cdr.read_marker_array(data)
        except cdr.CdrError as exc:
            self.count += 1
            self.first = self.first or str(exc)
            return None
        self.decoded += 1
        return markers


class _TopicReplay:
    """One topic's marker set at increasing times, from one pass over its messages."""

    def __init__(self, messages, undecodable: Undecodable) -> None:
        self._messages = messages
        self._pending: tuple[int, bytes] | None = None
        self.markers = MarkerSet()
        self.undecodable = undecodable

    def at(self, time_ns: int) -> MarkerSet:
        while True:
            if self._pending is None:
                self._pending = next(self._messages, None)
                if self._pending is None:
                    return self.markers
            stamp, data = self._pending
            if stamp > time_ns:
                return self.markers
            markers = self.undecodable.decode(data)
            if markers is not None:
                self.markers.apply(markers)
            self._pending = None


class _TransformReplay:
    """One TF topic's messages applied to :class:`Transforms` up to increasing times (undecodable ones skipped)."""

    def __init__(self, messages, transforms: Transforms) -> None:
        self._messages = messages
        self._pending: tuple[int, bytes] | None = None
        self.transforms = transforms

    def at(self, time_ns: int) -> Transforms:
        while True:
            if self._pending is None:
                self._pending = next(self._messages, None)
                if self._pending is None:
                    return self.transforms
            stamp, data = self._pending
            if stamp > time_ns:
                return self.transforms
            try:
                self.transforms.apply(cdr.read_tf_message(data))
            except cdr.CdrError:
                pass
            self._pending = None


class FrameSource:
    """Marker sets at increasing times, from one pass over the bag: the marker topic's and, beside it, its
    latched static markers' (each topic's DELETEALL clears that topic's markers only, as a viewer's display per
    topic does), placed by the bag's TF (:class:`~cgp_sim_ros.render.primitives.Transforms`)."""

    def __init__(self, stream: MarkerStream, undecodable: Undecodable | None = None) -> None:
        self.undecodable = undecodable or Undecodable()
        self._topics = [_TopicReplay(stream.messages(), self.undecodable)]
        if stream.static_topic:
            self._topics.insert(0, _TopicReplay(stream.messages(topic=stream.static_topic), self.undecodable))
        self.transforms = Transforms()
        self._tf = [_TransformReplay(stream.messages(topic=t), self.transforms) for t in stream.tf_topics]

    def at(self, time_ns: int) -> list:
        """The markers on display at ``time_ns``: every message logged at or before it applied (times must not
        decrease between calls)."""
        for replay in self._tf:
            replay.at(time_ns)
        return self.transforms.place([m for replay in self._topics for m in replay.at(time_ns).markers.values()])


def default_camera(stream: MarkerStream, times: np.ndarray, aspect: float, args,
                   undecodable: Undecodable | None = None) -> Camera:
    """Frame what is drawn at FRAMING_SAMPLES instants spread over ``times`` (each from the messages of the
    FRAMING_LOOKBACK_NS before it: mcap seeks there, so framing does not read the whole bag)."""
    samples = np.unique(times[np.linspace(0, len(times) - 1, min(FRAMING_SAMPLES, len(times))).round().astype(int)])
    points = []
    static = _TopicReplay(stream.messages(topic=stream.static_topic), undecodable or Undecodable()) \
        if stream.static_topic else None  # (few messages: read from the start)
    # TF: /tf_static from the start (few messages), /tf from the lookback window before each sample
    static_tf = [_TransformReplay(stream.messages(topic=t), Transforms()) for t in stream.tf_topics if "static" in t]
    for t in samples:
        transforms = Transforms()
        for replay in static_tf:
            transforms.apply(list(replay.at(int(t)).frames.values()))
        for topic in (name for name in stream.tf_topics if "static" not in name):
            _TransformReplay(stream.messages(int(t) - FRAMING_LOOKBACK_NS, int(t), topic=topic), transforms).at(int(t))
        markers = MarkerSet()
        for _stamp, data in stream.messages(int(t) - FRAMING_LOOKBACK_NS, int(t)):
            decoded = (undecodable or Undecodable()).decode(data)
            if decoded is not None:
                markers.apply(decoded)
        points.append(extent_points(transforms.place(markers.markers.values())))
        if static is not None:
            points.append(extent_points(transforms.place(static.at(int(t)).markers.values())))
    return Camera.framing(np.concatenate(points), aspect, azimuth_deg=args.azimuth,
                          elevation_deg=args.elevation, fov_deg=args.fov)


# ------------------------------------------------------------------------------------------------ writers
class _PngWriter:
    def __init__(self, path: Path, sequence: bool) -> None:
        self.path, self.sequence, self.index, self.written = path, sequence, 0, []

    def add(self, frame: np.ndarray) -> None:
        from PIL import Image

        target = Path(str(self.path) % self.index) if self.sequence else self.path
        Image.fromarray(frame).save(target)
        self.written.append(target)
        self.index += 1

    def close(self) -> None:
        pass


class _GifWriter:
    """All frames quantized to one palette (taken from the first frame) and written at close."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps, self.frames, self.palette = path, fps, [], None

    def add(self, frame: np.ndarray) -> None:
        from PIL import Image

        image = Image.fromarray(frame)
        if self.palette is None:
            # Median cut over the frame's *distinct* colours, each counted once: weighted by pixel count, the
            # sky and the ground would take the whole palette and a small red ball would come out orange.
            distinct = np.unique(frame.reshape(-1, 3), axis=0)
            self.palette = Image.fromarray(distinct[None]).quantize(colors=GIF_COLORS,
                                                                    method=Image.Quantize.MEDIANCUT)
        self.frames.append(image.quantize(palette=self.palette, dither=Image.Dither.NONE))

    def close(self) -> None:
        if self.frames:
            # GIF delays are whole centiseconds
            self.frames[0].save(self.path, save_all=True, append_images=self.frames[1:], loop=0,
                                duration=max(2, round(100 / self.fps)) * 10, optimize=False, disposal=1)


class _Mp4Writer:
    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        try:
            import imageio_ffmpeg
        except ImportError:
            raise RenderError("writing .mp4 needs the imageio-ffmpeg package (pip install imageio-ffmpeg); "
                              "or write a .gif or .png") from None
        self.path = path
        self._writer = imageio_ffmpeg.write_frames(
            str(path), size, fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p", quality=None,
            macro_block_size=1, output_params=["-crf", str(MP4_CRF), "-preset", "medium", "-movflags", "+faststart"],
            ffmpeg_log_level="error")
        self._writer.send(None)  # start ffmpeg

    def add(self, frame: np.ndarray) -> None:
        self._writer.send(np.ascontiguousarray(frame))

    def close(self) -> None:
        self._writer.close()


def _writer(path: Path, args, size: tuple[int, int]):
    suffix = path.suffix.lower()
    if suffix == ".png":
        return _PngWriter(path, sequence=bool(_PRINTF.search(path.name)))
    if suffix == ".gif":
        return _GifWriter(path, args.fps)
    return _Mp4Writer(path, args.fps, size)


# --------------------------------------------------------------------------------------------------- main
def render(args) -> dict:
    """Render as the parsed arguments say; returns what was done (frames, seconds, output)."""
    output = Path(args.output).expanduser()
    suffix = output.suffix.lower()
    if suffix not in FORMATS:
        raise RenderError(f"-o {args.output}: unknown format {output.suffix or '(no suffix)'!r}; use .mp4, .gif "
                          "or .png")
    if not output.parent.is_dir():
        raise RenderError(f"-o {args.output}: directory {output.parent} does not exist")
    if (output.exists() or output.is_symlink()) and not output.is_file():  # a FIFO would block the writer
        try:
            regular_file(output)
        except UserInputError as exc:
            raise RenderError(f"-o {args.output}: {exc}; the output must be a regular file") from None
    if not (args.fps > 0 and math.isfinite(args.fps)) or not (args.speed > 0 and math.isfinite(args.speed)):
        raise RenderError("--fps and --speed must be positive numbers")
    if not 1.0 <= args.fov <= 170.0:
        raise RenderError(f"--fov {args.fov:g}: must be within 1..170 degrees")
    width, height = args.size
    if suffix == ".mp4" and (width % 2 or height % 2):
        raise RenderError(f"--size {width}x{height}: H.264 (yuv420p) needs an even width and height")
    sequence = suffix == ".png" and bool(_PRINTF.search(output.name))
    eye_target = parse_camera(args.camera) if args.camera else None

    stream = open_marker_stream(args.bag, args.topic)
    undecodable = Undecodable()
    times = frame_times(stream, args.start, args.end, args.fps, args.speed, still=suffix == ".png" and not sequence)
    aspect = width / height
    if eye_target is None:
        camera = default_camera(stream, times, aspect, args, undecodable)
    else:
        eye, target = eye_target
        if target is None:
            target = default_camera(stream, times, aspect, args).target
        camera = Camera(eye=eye, target=target, fov_deg=args.fov)
    rasterizer = Rasterizer(width, height, supersample=args.supersample)
    progress = None if args.quiet else ProgressLine(sys.stderr)
    source = FrameSource(stream, undecodable)
    writer = _writer(output, args, (width, height))
    started = time.monotonic()
    skipped: set[str] = set()
    try:
        for index, stamp in enumerate(times):
            prims = primitives(source.at(int(stamp)))
            skipped |= prims.skipped
            writer.add(rasterizer.render(prims, camera))
            if progress is not None and (progress.due() or index + 1 == len(times)):
                done = index + 1
                elapsed = time.monotonic() - started
                rate = done / elapsed if elapsed > 0 else float("nan")
                progress.update(f"rendering {output.name}: {bar(done / len(times))} {done}/{len(times)} frames, "
                                f"t = {(stamp - stream.start_ns) / _NS:.2f} s, {rate:.1f} frames/s, "
                                f"ETA {format_duration((len(times) - done) / rate if rate > 0 else math.inf)}",
                                force=index + 1 == len(times))
    finally:
        writer.close()
        if progress is not None:
            progress.finish()
    elapsed = time.monotonic() - started
    if undecodable.count and not undecodable.decoded:
        raise RenderError(f"{args.bag}: none of its marker messages on {stream.topic} could be decoded "
                          f"({undecodable.count} tried; first: {undecodable.first})")
    notes = list((stream.damaged or {}).values())
    if undecodable.count:
        notes.append(f"{undecodable.count} undecodable marker message(s) skipped (first: {undecodable.first})")
    return {"output": output, "frames": len(times), "seconds": elapsed, "skipped": sorted(skipped),
            "camera": camera, "notes": notes}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        result = render(args)
    except (RenderError, BagError) as exc:
        print(f"cgp-sim-render: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # reading the bag or writing the output failed (permissions, a full disk, ...)
        print(f"cgp-sim-render: {exc.filename or args.output}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("cgp-sim-render: interrupted", file=sys.stderr)
        return 130
    camera = result["camera"]
    eye, target = np.round(camera.eye, 2), np.round(camera.target, 2)
    print(f"cgp-sim-render: {result['output']}: {result['frames']} frame(s) in {result['seconds']:.1f} s "
          f"(camera {','.join(f'{v:g}' for v in eye)}:{','.join(f'{v:g}' for v in target)})"
          + (f"; marker types not drawn: {', '.join(result['skipped'])}" if result["skipped"] else ""),
          file=sys.stderr)
    for note in result["notes"]:
        print(f"cgp-sim-render: note: {note}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
