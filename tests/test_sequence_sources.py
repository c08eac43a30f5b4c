"""Frame sources of calibrate-sequence: folders, two videos, side-by-side videos and ROS 1 / ROS 2 bags.

Every input is a small file written here (64-160 px, a few frames); decoded pixels are compared with what was
written: exactly for PNG, lossless video (FFV1) and raw bag messages, approximately for JPEG and MJPG.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.images import load_image
from stereogeo_cli.sequence.sources import FramePair, open_source

# ------------------------------------------------------------------------------------------------ inputs


def scene(height: int, width: int, seed: int) -> np.ndarray:
    """A smooth, colourful RGB image [H x W x 3] uint8, different for every seed (survives lossy codecs)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    channels = []
    for _ in range(3):
        fx, fy, phase = rng.uniform(0.02, 0.09, 2).tolist() + [rng.uniform(0, 6.3)]
        channels.append(127.5 + 100 * np.sin(fx * x + fy * y + phase))
    return np.clip(np.stack(channels, axis=-1), 0, 255).astype(np.uint8)


def noise(height: int, width: int, seed: int, channels: int = 3) -> np.ndarray:
    shape = (height, width, channels) if channels > 1 else (height, width)
    return np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    bgr = rgb if rgb.ndim == 2 else cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    assert cv2.imwrite(str(path), bgr)


def write_video(path: Path, frames: list[np.ndarray], fourcc: str, fps: float = 10.0) -> None:
    """RGB frames to a video with OpenCV's writer; skips the test where this OpenCV cannot write it."""
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (width, height))
    if not writer.isOpened():
        pytest.skip(f"this OpenCV cannot write {fourcc} to {path.suffix}")
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()


def write_y4m(path: Path, width: int, height: int, n: int) -> None:
    """An uncompressed YUV 4:4:4 video; any width (OpenCV's writer rounds odd widths down)."""
    with open(path, "wb") as f:
        f.write(f"YUV4MPEG2 W{width} H{height} F10:1 Ip A1:1 C444\n".encode())
        for i in range(n):
            f.write(b"FRAME\n" + np.full((3, height, width), 60 + 20 * i, np.uint8).tobytes())


ROS1 = get_typestore(Stores.ROS1_NOETIC)
ROS2 = get_typestore(Stores.ROS2_HUMBLE)
T0 = 1_700_000_000 * 10**9  # a bag's first stamp (ns)


def image_msg(
    store, stamp_ns: int, array: np.ndarray, encoding: str, *, pad: int = 0, bigendian: bool = False
):
    """sensor_msgs/Image of ``array`` [H x W (x C)] as it is stored (no conversion); ``pad`` bytes per row."""
    height, width = array.shape[:2]
    raw = array.astype(array.dtype.newbyteorder(">" if bigendian else "<")) if array.itemsize > 1 else array
    rows = raw.reshape(height, -1).view(np.uint8)
    rows = np.concatenate([rows, np.zeros((height, pad), np.uint8)], axis=1)
    return store.types["sensor_msgs/msg/Image"](
        header=header(store, stamp_ns),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=rows.shape[1],
        data=rows.reshape(-1),
    )


def compressed_msg(store, stamp_ns: int, rgb: np.ndarray, fmt: str):
    ok, data = cv2.imencode(f".{fmt}", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert ok
    return store.types["sensor_msgs/msg/CompressedImage"](
        header=header(store, stamp_ns), format=fmt, data=data.reshape(-1)
    )


def header(store, stamp_ns: int):
    time = store.types["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    extra = {"seq": 0} if store is ROS1 else {}
    return store.types["std_msgs/msg/Header"](stamp=time, frame_id="camera", **extra)


def write_bag(path: Path, topics: dict[str, list], ros: int = 1, plugin=StoragePlugin.SQLITE3) -> None:
    """``topics``: {name: [message, ...]}; each recorded 1 ms after its header stamp (T0 without a header)."""
    store = ROS1 if ros == 1 else ROS2
    writer = Writer1(path) if ros == 1 else Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        for topic, messages in topics.items():
            connection = writer.add_connection(topic, messages[0].__msgtype__, typestore=store)
            for msg in messages:
                stamp = msg.header.stamp if hasattr(msg, "header") else T0
                stamp = stamp if isinstance(stamp, int) else stamp.sec * 10**9 + stamp.nanosec
                serialize = store.serialize_ros1 if ros == 1 else store.serialize_cdr
                writer.write(connection, stamp + 1_000_000, serialize(msg, msg.__msgtype__))


def one_line_error(excinfo) -> str:
    message = str(excinfo.value)
    assert "\n" not in message and message
    assert excinfo.value.exit_code == 2
    return message


# ----------------------------------------------------------------------------------------------- folders


def test_folder_left_right_layout_natural_order_lazy_and_exact(tmp_path):
    images = {}
    for i, name in enumerate(["img1", "img2", "img10"]):
        images[name] = noise(64, 96, 2 * i), noise(64, 96, 2 * i + 1)
        write_png(tmp_path / "left" / f"{name}.png", images[name][0])
        write_png(tmp_path / "right" / f"{name}.png", images[name][1])
    write_png(tmp_path / "left" / "lonely.png", noise(64, 96, 99))  # no partner: left out, with a warning

    source = open_source(tmp_path)
    pairs = list(source)

    assert isinstance(pairs[0], FramePair)
    assert [p.name for p in pairs] == ["img1", "img2", "img10"]
    assert [p.index for p in pairs] == [0, 1, 2] and [p.time for p in pairs] == [0.0, 1.0, 2.0]
    for pair in pairs:
        assert pair.left.dtype == np.uint8 and pair.left.shape == (64, 96, 3)
        np.testing.assert_array_equal(pair.left, images[pair.name][0])
        np.testing.assert_array_equal(pair.right, images[pair.name][1])
    assert source.count() == 3
    assert "3 pairs" in source.description
    assert any("lonely" in w for w in source.warnings)
    assert [p.name for p in source] == ["img1", "img2", "img10"]  # iterable again


def test_folder_suffix_layout_loads_as_load_image_with_fps_times_and_every(tmp_path):
    for i in range(5):  # grey 16-bit left images, colour right images: read as calibrate reads them
        grey16 = noise(70, 80, i, channels=1).astype(np.uint16) * 257
        cv2.imwrite(str(tmp_path / f"f{i}_L.png"), grey16)
        write_png(tmp_path / f"f{i}_R.png", noise(70, 80, 10 + i))

    pairs = list(open_source(tmp_path, fps=20.0, every=2))

    assert [p.name for p in pairs] == ["f0", "f2", "f4"]
    assert [p.time for p in pairs] == pytest.approx([0.0, 0.1, 0.2])  # position in the folder / fps
    for pair in pairs:
        np.testing.assert_array_equal(pair.left, load_image(tmp_path / f"{pair.name}_L.png"))
        np.testing.assert_array_equal(pair.right, load_image(tmp_path / f"{pair.name}_R.png"))
    assert open_source(tmp_path, max_frames=2).count() == 2


def test_folder_frame_of_another_size_is_named(tmp_path):
    for i in range(3):
        write_png(tmp_path / "cam0" / f"{i}.png", noise(64, 96 if i < 2 else 100, i))
        write_png(tmp_path / "cam1" / f"{i}.png", noise(64, 96, 10 + i))
    source = open_source(tmp_path)
    with pytest.raises(StereoGeoError) as excinfo:
        list(source)
    message = one_line_error(excinfo)
    assert "2.png" in message and "100x64" in message and "96x64" in message


def test_missing_and_empty_inputs(tmp_path):
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(tmp_path / "nothing")
    assert "nothing" in one_line_error(excinfo)
    (tmp_path / "empty").mkdir()
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(tmp_path / "empty")
    assert "no stereo pairs" in one_line_error(excinfo)


def test_incompatible_arguments(tmp_path):
    write_png(tmp_path / "a_left.png", noise(64, 64, 1))
    write_png(tmp_path / "a_right.png", noise(64, 64, 2))
    video = tmp_path / "v.avi"
    for kwargs in (
        {"path": tmp_path, "video": (video, video)},
        {"path": tmp_path, "sbs": video},
        {"path": tmp_path, "left_topic": "/l", "right_topic": "/r"},
        {"sbs": video, "every": 2, "fps": 5.0},
        {},
        {"path": tmp_path, "every": 0},
        {"path": tmp_path, "fps": -1.0},
        {"path": tmp_path, "max_frames": 0},
    ):
        with pytest.raises(StereoGeoError) as excinfo:
            open_source(**kwargs)
        one_line_error(excinfo)


# ------------------------------------------------------------------------------------------------ videos


def test_two_lossless_videos_pair_by_frame_number_and_stop_at_the_shorter(tmp_path):
    left = [noise(64, 96, i) for i in range(5)]
    right = [noise(80, 112, 10 + i) for i in range(4)]  # other size, one frame fewer
    write_video(tmp_path / "l.mkv", left, "FFV1", fps=10)
    write_video(tmp_path / "r.mkv", right, "FFV1", fps=10)

    source = open_source(video=(tmp_path / "l.mkv", tmp_path / "r.mkv"))
    pairs = list(source)

    assert source.count() == 4 == len(pairs)
    assert [p.name for p in pairs] == [f"frame_{n:06d}" for n in range(4)]
    assert [p.time for p in pairs] == pytest.approx([0.0, 0.1, 0.2, 0.3], abs=2e-3)
    for n, pair in enumerate(pairs):
        np.testing.assert_array_equal(pair.left, left[n])
        np.testing.assert_array_equal(pair.right, right[n])
    assert any("shorter" in w for w in source.warnings)
    assert "l.mkv" in source.description and "r.mkv" in source.description


def _truncated_avi(path: Path, frames: list[np.ndarray], kept: int) -> None:
    """An MJPG AVI whose header declares every frame of ``frames`` but whose data ends after ``kept``: a
    recording cut short (the file copied while it was written, a camera that lost power)."""
    write_video(path, frames, "MJPG")
    data = path.read_bytes()
    movi = data.index(b"movi")
    chunks = [i for i in range(movi, len(data) - 4) if data[i : i + 4] == b"00dc"]  # one per frame
    path.write_bytes(data[: chunks[kept]])


def test_a_truncated_video_says_so(tmp_path):
    frames = [scene(96, 128, i) for i in range(14)]
    write_video(tmp_path / "l.avi", frames, "MJPG")
    _truncated_avi(tmp_path / "r.avi", frames, 8)
    source = open_source(video=(tmp_path / "l.avi", tmp_path / "r.avi"))
    assert len(list(source)) == 8
    (warning,) = [w for w in source.warnings if "truncated" in w]
    assert "r.avi" in warning and "8 frames" in warning and "14" in warning
    list(source)  # read again: said once
    assert sum("truncated" in w for w in source.warnings) == 1

    sbs = [np.concatenate([f, f], axis=1) for f in frames]
    _truncated_avi(tmp_path / "sbs.avi", sbs, 5)
    source = open_source(sbs=tmp_path / "sbs.avi")
    assert len(list(source)) == 5
    assert any("sbs.avi" in w and "truncated" in w for w in source.warnings)
    complete = open_source(video=(tmp_path / "l.avi", tmp_path / "l.avi"))
    assert len(list(complete)) == 14 and not complete.warnings


def test_mjpg_videos_decode_approximately(tmp_path):
    frames = [scene(96, 128, i) for i in range(3)]
    write_video(tmp_path / "l.avi", frames, "MJPG")
    write_video(tmp_path / "r.avi", frames[::-1], "MJPG")
    pairs = list(open_source(video=(tmp_path / "l.avi", tmp_path / "r.avi")))
    assert len(pairs) == 3
    for n, pair in enumerate(pairs):
        assert np.abs(pair.left.astype(int) - frames[n]).mean() < 4
        assert np.abs(pair.right.astype(int) - frames[2 - n]).mean() < 4


def test_side_by_side_video_splits_halves(tmp_path):
    halves = [(noise(64, 80, i), noise(64, 80, 10 + i)) for i in range(3)]
    write_video(tmp_path / "sbs.mkv", [np.concatenate(h, axis=1) for h in halves], "FFV1")
    pairs = list(open_source(sbs=tmp_path / "sbs.mkv"))
    assert len(pairs) == 3
    for pair, (left, right) in zip(pairs, halves, strict=True):
        np.testing.assert_array_equal(pair.left, left)
        np.testing.assert_array_equal(pair.right, right)


def test_side_by_side_video_of_odd_width_is_refused(tmp_path):
    write_y4m(tmp_path / "odd.y4m", 129, 64, 2)
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(sbs=tmp_path / "odd.y4m")
    assert "odd.y4m" in one_line_error(excinfo) and "129" in str(excinfo.value)


def test_video_subsampling_every_fps_and_max_frames(tmp_path):
    frames = [noise(64, 64, i) for i in range(8)]  # 10 fps: frame n at n / 10 s
    write_video(tmp_path / "sbs.mkv", [np.concatenate([f, f[::-1]], axis=1) for f in frames], "FFV1")
    path = tmp_path / "sbs.mkv"
    for kwargs, numbers in (
        ({"every": 3}, [0, 3, 6]),
        ({"fps": 5.0}, [0, 2, 4, 6]),
        ({"fps": 3.0}, [0, 4]),  # at least 1/3 s apart: 0.4 s steps
        ({"max_frames": 2}, [0, 1]),
        ({"every": 2, "max_frames": 3}, [0, 2, 4]),
    ):
        source = open_source(sbs=path, **kwargs)
        pairs = list(source)
        assert [p.name for p in pairs] == [f"frame_{n:06d}" for n in numbers], kwargs
        assert [p.index for p in pairs] == list(range(len(numbers)))
        assert source.count() == len(numbers)
        for pair, n in zip(pairs, numbers, strict=True):
            np.testing.assert_array_equal(pair.left, frames[n])


def test_corrupt_and_missing_videos(tmp_path):
    (tmp_path / "junk.mp4").write_bytes(np.random.default_rng(0).integers(0, 256, 4000, np.uint8).tobytes())
    write_video(tmp_path / "ok.mkv", [noise(64, 64, 0)], "FFV1")
    for kwargs, named in (
        ({"video": (tmp_path / "junk.mp4", tmp_path / "ok.mkv")}, "junk.mp4"),
        ({"sbs": tmp_path / "junk.mp4"}, "junk.mp4"),
        ({"video": (tmp_path / "ok.mkv", tmp_path / "gone.mp4")}, "gone.mp4"),
    ):
        with pytest.raises(StereoGeoError) as excinfo:
            open_source(**kwargs)
        assert named in one_line_error(excinfo)


# -------------------------------------------------------------------------------------------------- bags


def test_ros1_bag_raw_images_paired_by_stamp_with_an_offset(tmp_path):
    lefts = [noise(64, 80, i, channels=1) for i in range(4)]
    rights = [noise(64, 80, 10 + i) for i in range(5)]
    step = 100_000_000  # 10 Hz
    left_msgs = [image_msg(ROS1, T0 + i * step, im, "mono8", pad=4) for i, im in enumerate(lefts)]
    # the right camera's stamps 3 ms later; its extra last frame has no left partner
    right_msgs = [image_msg(ROS1, T0 + i * step + 3_000_000, im, "rgb8") for i, im in enumerate(rights)]
    write_bag(tmp_path / "run.bag", {"/left/image_raw": left_msgs, "/right/image_raw": right_msgs})

    source = open_source(tmp_path / "run.bag", left_topic="/left/image_raw", right_topic="/right/image_raw")
    pairs = list(source)

    assert source.count() == 4 == len(pairs)
    assert [p.time for p in pairs] == pytest.approx([(T0 + i * step) / 1e9 for i in range(4)], abs=1e-6)
    assert [p.name for p in pairs] == [f"frame_{i:06d}" for i in range(4)]
    for i, pair in enumerate(pairs):
        np.testing.assert_array_equal(pair.left, np.repeat(lefts[i][..., None], 3, axis=2))
        np.testing.assert_array_equal(pair.right, rights[i])
    assert any("1 of 5 right" in w for w in source.warnings)
    assert "run.bag" in source.description

    with pytest.raises(StereoGeoError) as excinfo:  # 3 ms apart, 1 ms allowed: nothing pairs
        open_source(tmp_path / "run.bag", left_topic="/left/image_raw", right_topic="/right/image_raw",
                    tolerance_s=0.001)  # fmt: skip
    assert "0.003 s" in one_line_error(excinfo)


def test_ros1_bag_encodings(tmp_path):
    rgb = scene(64, 96, 1)
    grey16 = np.random.default_rng(3).integers(0, 65536, (64, 96), dtype=np.uint16)
    mosaic = np.zeros((64, 96), np.uint8)  # RGGB: R at even rows and columns, B at odd ones
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = rgb[0::2, 0::2, 0], rgb[0::2, 1::2, 1]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = rgb[1::2, 0::2, 1], rgb[1::2, 1::2, 2]
    bgra = np.concatenate([rgb[..., ::-1], np.full((64, 96, 1), 7, np.uint8)], axis=2)
    topics = {
        "/bgr8": [image_msg(ROS1, T0, np.ascontiguousarray(rgb[..., ::-1]), "bgr8")],
        "/bgra8": [image_msg(ROS1, T0, bgra, "bgra8")],
        "/mono16": [image_msg(ROS1, T0, grey16, "mono16", bigendian=True)],
        "/bayer": [image_msg(ROS1, T0, mosaic, "bayer_rggb8")],
        "/float": [image_msg(ROS1, T0, np.zeros((64, 96), np.float32), "32FC1")],
        "/odometry": [ROS1.types["std_msgs/msg/String"](data="not an image")],
    }
    write_bag(tmp_path / "enc.bag", topics)
    bag = tmp_path / "enc.bag"

    pair = next(iter(open_source(bag, left_topic="/bgr8", right_topic="/bgra8")))
    np.testing.assert_array_equal(pair.left, rgb)
    np.testing.assert_array_equal(pair.right, rgb)
    pair = next(iter(open_source(bag, left_topic="/mono16", right_topic="/bayer")))
    np.testing.assert_array_equal(pair.left[..., 0], ((grey16.astype(np.uint32) * 255 + 32767) // 65535))
    # demosaicing is approximate on a smooth image, but a swapped pattern would put red where blue is
    error = np.abs(pair.right[4:-4, 4:-4].astype(int) - rgb[4:-4, 4:-4])
    assert error.mean() < 2 and np.abs(rgb[..., 0].astype(int) - rgb[..., 2]).mean() > 30

    with pytest.raises(StereoGeoError) as excinfo:
        open_source(bag, left_topic="/bgr8", right_topic="/float")
    assert "32FC1" in one_line_error(excinfo) and "/float" in str(excinfo.value)
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(bag, left_topic="/bgr8", right_topic="/odometry")
    assert "not images" in one_line_error(excinfo)


def test_ros2_bag_compressed_jpeg_and_png(tmp_path):
    lefts = [scene(96, 128, i) for i in range(3)]
    rights = [noise(96, 128, 10 + i) for i in range(3)]
    step = 50_000_000
    write_bag(
        tmp_path / "bag2",
        {
            "/cam0/compressed": [
                compressed_msg(ROS2, T0 + i * step, im, "jpeg") for i, im in enumerate(lefts)
            ],
            "/cam1/compressed": [
                compressed_msg(ROS2, T0 + i * step - 2_000_000, im, "png") for i, im in enumerate(rights)
            ],
        },
        ros=2,
    )
    db3 = next((tmp_path / "bag2").glob("*.db3"))
    for given in (tmp_path / "bag2", db3):  # the bag's folder, or its storage file
        source = open_source(given, left_topic="/cam0/compressed", right_topic="/cam1/compressed")
        pairs = list(source)
        assert len(pairs) == 3 == source.count()
        for i, pair in enumerate(pairs):
            assert pair.time == pytest.approx((T0 + i * step) / 1e9, abs=1e-6)
            assert np.abs(pair.left.astype(int) - lefts[i]).mean() < 4
            np.testing.assert_array_equal(pair.right, rights[i])


def test_ros2_mcap_bag_subsampling_and_missing_topics(tmp_path):
    step = 20_000_000  # 50 Hz
    lefts = [noise(64, 64, i, channels=1) for i in range(10)]
    rights = [noise(64, 64, 50 + i, channels=1) for i in range(10)]
    not_an_image = ROS2.types["std_msgs/msg/Header"](stamp=header(ROS2, T0).stamp, frame_id="x")
    topics = {
        "/left": [image_msg(ROS2, T0 + i * step, im, "mono8") for i, im in enumerate(lefts)],
        "/right": [image_msg(ROS2, T0 + i * step + 500_000, im, "mono8") for i, im in enumerate(rights)],
        "/right/camera_info": [not_an_image],
    }
    write_bag(tmp_path / "mcap", topics, ros=2, plugin=StoragePlugin.MCAP)
    bag = tmp_path / "mcap"
    topics = {"left_topic": "/left", "right_topic": "/right"}
    for kwargs, numbers in (
        ({"every": 4}, [0, 4, 8]),
        ({"fps": 10.0}, [0, 5]),
        ({"fps": 25.0, "max_frames": 3}, [0, 2, 4]),
    ):
        source = open_source(bag, **topics, **kwargs)
        pairs = list(source)
        assert [p.name for p in pairs] == [f"frame_{n:06d}" for n in numbers], kwargs
        assert source.count() == len(numbers)
        for pair, n in zip(pairs, numbers, strict=True):
            np.testing.assert_array_equal(pair.left[..., 1], lefts[n])

    with pytest.raises(StereoGeoError) as excinfo:
        open_source(bag, left_topic="/left", right_topic="/cam1/image_raw")
    message = one_line_error(excinfo)
    assert "/cam1/image_raw" in message and "/left" in message and "/right" in message
    assert "camera_info" not in message  # only the image topics are listed
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(bag, left_topic="/left")
    assert "--right-topic" in one_line_error(excinfo)


def test_bag_frame_of_another_size_is_named_before_reading(tmp_path):
    sizes = [(64, 80), (64, 80), (72, 80)]
    lefts = [image_msg(ROS1, T0 + i * 10**8, noise(h, w, i, 1), "mono8") for i, (h, w) in enumerate(sizes)]
    rights = [image_msg(ROS1, T0 + i * 10**8, noise(64, 80, 9 + i, 1), "mono8") for i in range(3)]
    write_bag(tmp_path / "sizes.bag", {"/l": lefts, "/r": rights})
    with pytest.raises(StereoGeoError) as excinfo:
        open_source(tmp_path / "sizes.bag", left_topic="/l", right_topic="/r")
    message = one_line_error(excinfo)
    assert "/l" in message and "frame 2" in message and "80x72" in message
