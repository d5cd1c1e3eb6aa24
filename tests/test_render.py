"""cgp-sim-render as a user meets it: a bag the node recorded becomes a GIF / MP4 / PNG that a reader opens —
the size and frame count asked for, the falling ball's pixels moving down the picture, the colours of the
scene's markers in it — without rclpy (it must run where ROS cannot be imported), and bad arguments refused
with the reason.  Timing is benchmarks/bench_render.py's business."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from conftest import VENV_BIN
from PIL import Image

from cgp_sim_ros.wire import cdr

RENDER = str(VENV_BIN / "cgp-sim-render")
BALL = (0.9, 0.25, 0.2)  # the default scene's colours (msgs_config/scenes/default.yaml, messages.FLOCK_COLORS)
CRATE = (0.75, 0.55, 0.3)
FISH = (0.95, 0.6, 0.15)
# A side view of the default scene, level with the ball's drop: the ball falls straight down the picture.
SIDE_CAMERA = "0,-16,2.5:0,0,2.5"


@pytest.fixture(scope="module")
def default_bag(tmp_path_factory):
    """1.2 s of the default scene, recorded by the installed node (the ball drops from 4 m: at 1.2 s it is
    on the ground)."""
    bag = tmp_path_factory.mktemp("render") / "bag"
    out = subprocess.run([str(VENV_BIN / "cgp-sim"), "--realtime", "false", "--duration", "1.2", "--bag", str(bag)],
                         capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr
    return bag


def render(*args: str, expect: int = 0, command: list[str] | None = None) -> subprocess.CompletedProcess:
    out = subprocess.run((command or [RENDER]) + list(args), capture_output=True, text=True, timeout=300)
    assert out.returncode == expect, out.stderr
    return out


def pixels_of(image: np.ndarray, color, max_angle_deg: float = 4.0, min_brightness: float = 0.15) -> np.ndarray:
    """(n, 2) row, column of the pixels whose colour is a shade of ``color`` (within a small angle of it as an
    RGB direction: Lambert shading scales a colour, it does not turn it)."""
    rgb = image[..., :3].astype(float) / 255.0
    direction = np.asarray(color, float) / np.linalg.norm(color)
    norm = np.linalg.norm(rgb, axis=-1)
    cosine = (rgb @ direction) / np.maximum(norm, 1e-9)
    mask = (cosine > np.cos(np.radians(max_angle_deg))) & (norm > min_brightness)
    return np.argwhere(mask)


def gif_frames(path) -> list[np.ndarray]:
    frames = []
    with Image.open(path) as gif:
        for index in range(gif.n_frames):
            gif.seek(index)
            frames.append(np.asarray(gif.convert("RGB")))
    return frames


def test_gif_of_a_recorded_bag_shows_the_ball_falling(default_bag, tmp_path):
    gif = tmp_path / "fall.gif"
    out = render(str(default_bag), "-o", str(gif), "--fps", "10", "--to", "1.0", "--size", "320x180",
                 "--camera", SIDE_CAMERA)
    assert "11 frame(s)" in out.stderr
    frames = gif_frames(gif)
    assert len(frames) == 11 and frames[0].shape == (180, 320, 3)
    with Image.open(gif) as image:
        assert image.info["loop"] == 0 and image.info["duration"] == 100  # ms per frame at 10 fps
    # the ball (red) is in every frame; its image centre moves down (rows grow), not sideways
    centres = []
    for frame in frames:
        ball = pixels_of(frame, BALL)
        assert len(ball) >= 8, "the ball is not in the picture"
        centres.append(ball.mean(axis=0))
    centres = np.array(centres)
    assert np.all(np.diff(centres[:8, 0]) > 0)  # falling for the first 0.7 s (it lands at ~0.8 s)
    assert centres[7, 0] - centres[0, 0] > 25
    assert np.ptp(centres[:8, 1]) < 3
    # the crate and the fish are drawn in their colours too
    assert len(pixels_of(frames[-1], CRATE)) >= 8
    assert len(pixels_of(frames[-1], FISH)) >= 8


def test_default_camera_frames_the_scene(default_bag, tmp_path):
    """Without --camera: the ball, the crate and the fish are all in the picture, and the picture is not
    empty sky or ground."""
    png = tmp_path / "still.png"
    render(str(default_bag), "-o", str(png), "--from", "0.5", "--size", "480x270", "-q")
    image = np.asarray(Image.open(png).convert("RGB"))
    assert image.shape == (270, 480, 3)
    for color in (BALL, CRATE, FISH):
        assert len(pixels_of(image, color)) >= 5, color


def test_png_sequence_and_still_agree(default_bag, tmp_path):
    render(str(default_bag), "-o", str(tmp_path / "f_%03d.png"), "--from", "0.2", "--to", "0.4", "--fps", "10",
           "--size", "160x90", "--camera", SIDE_CAMERA, "--supersample", "1", "-q")
    names = sorted(p.name for p in tmp_path.glob("f_*.png"))
    assert names == ["f_000.png", "f_001.png", "f_002.png"]
    render(str(default_bag), "-o", str(tmp_path / "still.png"), "--from", "0.3", "--size", "160x90",
           "--camera", SIDE_CAMERA, "--supersample", "1", "-q")
    still = np.asarray(Image.open(tmp_path / "still.png"))
    assert np.array_equal(np.asarray(Image.open(tmp_path / "f_001.png")), still)


def test_mp4_has_the_frames_and_size_asked_for(default_bag, tmp_path):
    import imageio_ffmpeg

    mp4 = tmp_path / "run.mp4"
    render(str(default_bag), "-o", str(mp4), "--fps", "20", "--to", "1.0", "--size", "320x180", "-q")
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8).reshape(180, 320, 3) for f in reader]
    assert meta["size"] == (320, 180) and meta["fps"] == 20
    assert len(frames) == 21
    assert len(pixels_of(frames[10], BALL, max_angle_deg=8)) >= 5  # H.264 shifts colours a little


def test_runs_where_rclpy_cannot_be_imported(default_bag, tmp_path):
    """The renderer in a Python where importing rclpy or any ROS message package fails (as on a machine
    without ROS): it still reads the bag and writes the picture."""
    code = textwrap.dedent(f"""
        import importlib.abc, sys
        BLOCKED = ("rclpy", "rosidl_runtime_py", "rpyutils", "ament_index_python", "geometry_msgs",
                   "visualization_msgs", "std_msgs", "nav_msgs", "rosgraph_msgs", "builtin_interfaces")
        class NoRos(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in BLOCKED or name.endswith("_msgs"):
                    raise ImportError(f"no ROS here: {{name}}")
        sys.meta_path.insert(0, NoRos())
        try:
            import rclpy
        except ImportError:
            pass
        else:
            sys.exit("rclpy imported")
        from cgp_sim_ros.render.cli import main
        sys.exit(main({[str(default_bag), "-o", str(tmp_path / "noros.png"), "--from", "0.5", "-q"]!r}))
    """)
    render(command=[sys.executable, "-c", code])
    assert len(pixels_of(np.asarray(Image.open(tmp_path / "noros.png").convert("RGB")), BALL)) >= 5


def _marker_bag(path, messages, static=()):
    """A bag written with the project's BagWriter: [(time_s, [marker bytes...]), ...] on /cgp_sim/markers (and
    ``static`` likewise on /cgp_sim/static_markers)."""
    from cgp_sim_ros.wire.bag import BagWriter

    timeline = sorted([(t, "/cgp_sim/markers", m) for t, m in messages]
                      + [(t, "/cgp_sim/static_markers", m) for t, m in static], key=lambda x: x[0])
    with BagWriter(path) as writer:
        writer.add_topic("/cgp_sim/markers", "visualization_msgs/msg/MarkerArray")
        if static:
            writer.add_topic("/cgp_sim/static_markers", "visualization_msgs/msg/MarkerArray")
        for t, topic, markers in timeline:
            stamp = round(t * 1e9)
            writer.write(topic, cdr.marker_array(markers), stamp, stamp)


def test_static_meshes_are_drawn_from_their_latched_topic(tmp_path):
    """Issue 38: the node sends the static meshes once, on ~/static_markers (a DELETEALL, then the set), not on
    every ~/markers array.  The renderer draws them with the markers of the same instant; a DELETEALL on
    ~/markers (a reset) does not remove them, a new ~/static_markers message replaces them."""
    red = dict(marker_type=cdr.SPHERE, ns="bodies/a", id=0, scale=(1, 1, 1), color=(1.0, 0.1, 0.1, 1.0))
    land = dict(marker_type=cdr.TRIANGLE_LIST, ns="bodies/land", id=0, color=(0.1, 0.2, 1.0, 1.0),
                points=np.array([[-3, 0, -1], [3, 0, -1], [0, 0, 1.5]], float))
    _marker_bag(tmp_path / "bag", [
        (0.0, [cdr.marker(cdr.MarkerFields(**red, position=(-1.5, -1, 0)))]),
        (1.0, [cdr.marker_deleteall(), cdr.marker(cdr.MarkerFields(**red, position=(1.5, -1, 0)))]),
        (2.0, [cdr.marker(cdr.MarkerFields(**red, position=(1.5, -1, 0)))]),
    ], static=[(0.0, [cdr.marker_deleteall(), cdr.marker(cdr.MarkerFields(**land))]),
               (1.5, [cdr.marker_deleteall()])])
    seen = {}
    for t in (0.5, 1.2, 1.8):
        png = tmp_path / f"t{t}.png"
        render(str(tmp_path / "bag"), "-o", str(png), "--from", str(t), "--camera", "0,-8,0:0,0,0",
               "--size", "200x100", "-q")
        image = np.asarray(Image.open(png).convert("RGB"))
        seen[t] = (len(pixels_of(image, (1.0, 0.1, 0.1))), len(pixels_of(image, (0.1, 0.2, 1.0))))
    assert seen[0.5][0] > 50 and seen[0.5][1] > 50  # the ball and the mesh sent once at t = 0
    assert seen[1.2][0] > 50 and seen[1.2][1] > 50  # the reset's DELETEALL on ~/markers keeps the mesh
    assert seen[1.8][0] > 50 and seen[1.8][1] == 0  # the mesh deleted: the new static set is empty


def test_markers_as_a_viewer_replays_them(tmp_path):
    """Frame at t = the latest message at or before t; DELETEALL (the node sends one after ~/reset) removes
    what came before; a sparse stream (markers_every > 1) holds the last state between messages."""
    red = dict(marker_type=cdr.SPHERE, ns="bodies/a", id=0, scale=(1, 1, 1), color=(1.0, 0.1, 0.1, 1.0))
    blue = dict(marker_type=cdr.CUBE, ns="bodies/b", id=0, scale=(1, 1, 1), color=(0.1, 0.2, 1.0, 1.0))
    _marker_bag(tmp_path / "bag", [
        (0.0, [cdr.marker(cdr.MarkerFields(**red, position=(-1.5, 0, 0)))]),
        (1.0, [cdr.marker(cdr.MarkerFields(**red, position=(1.5, 0, 0)))]),  # moved
        (2.0, [cdr.marker_deleteall(),
               cdr.marker(cdr.MarkerFields(**blue, position=(0, 0, 0)))]),  # reset: only the cube
        (3.0, [cdr.marker(cdr.MarkerFields(marker_type=cdr.SPHERE, ns="bodies/a", id=0,
                                           action=cdr.DELETE))]),  # no-op
    ])
    seen = {}
    for t in (0.5, 1.5, 2.5, 3.0):
        png = tmp_path / f"t{t}.png"
        render(str(tmp_path / "bag"), "-o", str(png), "--from", str(t), "--camera", "0,-8,0:0,0,0",
               "--size", "200x100", "-q")
        image = np.asarray(Image.open(png).convert("RGB"))
        reds, blues = pixels_of(image, (1.0, 0.1, 0.1)), pixels_of(image, (0.1, 0.2, 1.0))
        seen[t] = (len(reds), reds[:, 1].mean() if len(reds) else None, len(blues))
    assert seen[0.5][0] > 50 and seen[0.5][1] < 100 and seen[0.5][2] == 0  # red on the left
    assert seen[1.5][0] > 50 and seen[1.5][1] > 100 and seen[1.5][2] == 0  # red moved right
    assert seen[2.5][0] == 0 and seen[2.5][2] > 50  # DELETEALL: only the blue cube
    assert seen[3.0] == seen[2.5]


def test_a_hull_marker_is_drawn_at_its_pose(tmp_path):
    """Issue 25's hull and mesh markers: a TRIANGLE_LIST in the body frame whose pose moves it (as RViz and
    Foxglove draw it) — the renderer draws its triangles where the pose puts them, the same points each time."""
    from cgp_core.collision.meshfile import load_mesh
    from cgp_core.scene import builtin_mesh_dir

    vertices, triangles = load_mesh(builtin_mesh_dir() / "rock.stl")
    rock = dict(marker_type=cdr.TRIANGLE_LIST, ns="bodies/rock", id=0, points=4 * vertices[triangles].reshape(-1, 3),
                color=(1.0, 0.1, 0.1, 1.0))
    quarter = (0.0, 0.0, 0.7071067811865476, 0.7071067811865476)
    _marker_bag(tmp_path / "bag", [(0.0, [cdr.marker(cdr.MarkerFields(**rock, position=(-1.5, 0, 0)))]),
                                   (1.0, [cdr.marker(cdr.MarkerFields(**rock, position=(1.5, 0, 0.2),
                                                                      orientation=quarter))]),
                                   (2.0, [])])
    seen = {}
    for t in (0.5, 1.5):
        png = tmp_path / f"t{t}.png"
        render(str(tmp_path / "bag"), "-o", str(png), "--from", str(t), "--camera", "0,-8,0:0,0,0",
               "--size", "200x100", "-q")
        reds = pixels_of(np.asarray(Image.open(png).convert("RGB")), (1.0, 0.1, 0.1))
        seen[t] = (len(reds), reds[:, 1].mean() if len(reds) else None)
    assert seen[0.5][0] > 50 and seen[0.5][1] < 100  # on the left
    assert seen[1.5][0] > 50 and seen[1.5][1] > 100  # moved right by its pose


@pytest.mark.parametrize("args, says", [
    (["-o", "{tmp}/x.avi"], "unknown format '.avi'"),
    (["-o", "{tmp}/nodir/x.gif"], "does not exist"),
    (["-o", "{tmp}/x.gif", "--from", "99"], "--from 99: the bag spans 0 to"),
    (["-o", "{tmp}/x.gif", "--camera", "1,2"], "--camera: eye '1,2' is not three"),
    (["-o", "{tmp}/x.mp4", "--size", "321x180"], "needs an even width and height"),
    (["-o", "{tmp}/x.gif", "--topic", "/nope"], "no visualization_msgs/msg/MarkerArray messages on /nope"),
])
def test_bad_arguments_are_refused_with_the_reason(default_bag, tmp_path, args, says):
    out = render(str(default_bag), *[a.format(tmp=tmp_path) for a in args], expect=2)
    assert out.stderr.startswith("cgp-sim-render: ") and says in out.stderr, out.stderr
    assert not list(tmp_path.glob("x.*"))


def test_a_missing_or_broken_bag_is_refused(tmp_path):
    out = render(str(tmp_path / "missing"), "-o", str(tmp_path / "x.gif"), expect=2)
    assert "no such bag" in out.stderr
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all" * 10)
    out = render(str(tmp_path / "junk.mcap"), "-o", str(tmp_path / "x.gif"), expect=2)
    assert "not a readable MCAP file" in out.stderr


def test_bad_bags_are_named_errors_never_tracebacks_and_a_fifo_never_blocks(tmp_path):
    """Issue 38, D16: a metadata.yaml of random bytes, one whose ``rosbag2_bagfile_information`` is a list, a
    ``.mcap`` that is a directory, a FIFO as the bag, inside a bag directory or as the output: each is refused
    with exit 2 naming the file and what it is (a FIFO used to block the renderer for ever; the others were
    UnicodeDecodeError / AttributeError / IsADirectoryError tracebacks)."""
    import os

    cases = []
    garbage = tmp_path / "garbage"
    garbage.mkdir()
    (garbage / "metadata.yaml").write_bytes(np.random.default_rng(38).integers(0, 256, 3000, np.uint8).tobytes())
    cases.append((garbage, "metadata.yaml: not a rosbag2 metadata file"))
    listed = tmp_path / "listed"
    listed.mkdir()
    (listed / "metadata.yaml").write_text("rosbag2_bagfile_information: [1, 2]\n")
    cases.append((listed, "metadata.yaml: not a rosbag2 metadata file (no mapping rosbag2_bagfile_information)"))
    paths = tmp_path / "paths"
    paths.mkdir()
    (paths / "metadata.yaml").write_text("rosbag2_bagfile_information: {relative_file_paths: 7}\n")
    cases.append((paths, "relative_file_paths is not a list of file names"))
    directory = tmp_path / "dir"
    (directory / "run_0.mcap").mkdir(parents=True)
    cases.append((directory, "run_0.mcap: is a directory, not a regular file"))
    fifo_inside = tmp_path / "fifo_inside"
    fifo_inside.mkdir()
    os.mkfifo(fifo_inside / "run_0.mcap")
    cases.append((fifo_inside, "run_0.mcap: is a FIFO (named pipe), not a regular file"))
    fifo = tmp_path / "bag.mcap"
    os.mkfifo(fifo)
    cases.append((fifo, "bag.mcap: is a FIFO (named pipe), not a regular file"))
    for bag, says in cases:
        out = render(str(bag), "-o", str(tmp_path / "x.gif"), expect=2)
        assert out.stderr.startswith("cgp-sim-render: ") and says in out.stderr, out.stderr
        assert "Traceback" not in out.stderr
    os.mkfifo(tmp_path / "out.gif")
    out = render(str(fifo), "-o", str(tmp_path / "out.gif"), expect=2)
    assert "-o " in out.stderr and "is a FIFO (named pipe), not a regular file" in out.stderr, out.stderr
