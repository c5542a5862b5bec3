"""Cameras: gray conversion and resizing, VideoCapture on a real video file, image sequences, failure paths."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from jaxrecog.hardware.devices.camera import CameraError, CameraLostError, ImageSequenceCamera, VideoCamera, to_gray

H, W = 120, 160


def bt601(bgr: np.ndarray) -> np.ndarray:
    b, g, r = (bgr[..., i].astype(float) for i in range(3))
    return 0.299 * r + 0.587 * g + 0.114 * b


def test_to_gray_conversions(rng):
    bgr = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    out = to_gray(bgr, (H, W))
    assert out.dtype == np.uint8 and out.shape == (H, W)
    assert np.abs(out.astype(float) - bt601(bgr)).max() <= 1.0
    bgra = np.concatenate([bgr, np.full((H, W, 1), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(to_gray(bgra, (H, W)), out)
    g16 = rng.integers(0, 65536, (H, W), dtype=np.uint16)
    np.testing.assert_array_equal(to_gray(g16, (H, W)), (g16 >> 8).astype(np.uint8))
    f = rng.random((H, W))
    np.testing.assert_array_equal(to_gray(f, (H, W)), np.rint(f * 255).astype(np.uint8))
    gray = rng.integers(0, 256, (H, W, 1), dtype=np.uint8)
    np.testing.assert_array_equal(to_gray(gray, (H, W)), gray[:, :, 0])


def test_to_gray_resizes_to_the_model_size():
    # a 2x larger image of 2x2 constant blocks shrinks (area average) to exactly the blocks
    small = np.arange(H * W, dtype=np.int64).reshape(H, W) % 251
    big = np.kron(small, np.ones((2, 2), np.int64)).astype(np.uint8)
    np.testing.assert_array_equal(to_gray(big, (H, W)), small.astype(np.uint8))
    up = to_gray(np.full((30, 40), 99, np.uint8), (H, W))
    assert up.shape == (H, W) and np.all(up == 99)


@pytest.mark.parametrize(
    "frame,match",
    [
        (np.zeros((0, 4), np.uint8), "empty"),
        (np.zeros((4, 4, 2), np.uint8), "shape"),
        (np.zeros((4, 4), np.int32), "dtype"),
        (np.full((4, 4), np.nan), "NaN"),
    ],
)
def test_to_gray_rejects(frame, match):
    with pytest.raises(CameraError, match=match):
        to_gray(frame, (H, W))


def test_video_camera_reads_a_video_file(tmp_path):
    path = str(tmp_path / "clip.avi")
    levels = [40, 90, 140, 190]
    vw = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (320, 240))
    assert vw.isOpened()
    for v in levels:
        frame = np.zeros((240, 320, 3), np.uint8)
        frame[..., 1] = v  # pure green: gray = 0.587 v
        frame[:120, :, 2] = 255  # top half also red
        vw.write(frame)
    vw.release()
    cam = VideoCamera(path, image_shape=(H, W))
    for v in levels:
        img = cam.read()
        assert img.dtype == np.uint8 and img.shape == (H, W)
        bottom, top = img[70:, :].mean(), img[:50, :].mean()
        assert abs(bottom - 0.587 * v) < 4  # JPEG noise
        assert abs(top - (0.587 * v + 0.299 * 255)) < 4
    with pytest.raises(CameraError, match="no usable frame after 4 attempts"):
        cam.read()  # end of file: every retry fails
    cam.close()


def test_video_camera_reads_an_image_sequence_pattern(tmp_path, rng):
    frames = [rng.integers(1, 256, (H, W), dtype=np.uint8) for _ in range(3)]
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"f{i:03d}.png"), f)
    cam = VideoCamera(str(tmp_path / "f%03d.png"), image_shape=(H, W))
    for f in frames:
        got = cam.read()
        assert np.abs(got.astype(int) - f.astype(int)).max() <= 1  # lossless PNG; gray via BGR at most +-1


class FakeCapture:
    """Plays a script of (ok, frame) results."""

    def __init__(self, script, opened=True):
        self.script = list(script)
        self.opened = opened
        self.reads = 0
        self.released = False

    def isOpened(self):
        return self.opened

    def read(self):
        self.reads += 1
        if not self.script:
            return False, None
        return self.script.pop(0)

    def release(self):
        self.released = True


def test_black_and_failed_frames_are_retried(rng):
    good = rng.integers(1, 256, (H, W, 3), dtype=np.uint8)
    black = np.zeros((H, W, 3), np.uint8)
    fake = FakeCapture([(False, None), (True, black), (True, None), (True, good)])
    cam = VideoCamera("fake", capture_factory=lambda s: fake, retries=3)
    img = cam.read()
    assert fake.reads == 4
    assert np.abs(img.astype(float) - bt601(good)).max() <= 1.0


def test_black_level_threshold():
    dim = np.full((H, W), 3, np.uint8)
    fake = FakeCapture([(True, dim)] * 3)
    cam = VideoCamera("fake", capture_factory=lambda s: fake, retries=2, black_level=5)
    with pytest.raises(CameraError, match=r"'fake'.*3 attempts.*black frame"):
        cam.read()
    assert fake.reads == 3


def test_persistent_failure_is_a_clear_error():
    fake = FakeCapture([])
    cam = VideoCamera(3, capture_factory=lambda s: fake, retries=4)
    with pytest.raises(CameraError, match="source 3: no usable frame after 5 attempts: VideoCapture.read returned no frame"):
        cam.read()
    assert fake.reads == 5
    cam.close()
    assert fake.released
    with pytest.raises(CameraError, match="closed"):
        cam.read()


class HangingCapture:
    """A capture whose read blocks until ``go`` is set (a driver stuck in the device)."""

    def __init__(self):
        self.go, self.released = threading.Event(), threading.Event()

    def isOpened(self):
        return True

    def read(self):
        self.go.wait(10.0)
        return True, np.full((H, W), 100, np.uint8)

    def release(self):
        self.released.set()


def test_a_read_that_blocks_is_given_up_after_read_timeout_s_in_one_line():
    """A camera whose read blocked used to block ``read()`` (and the rig's ``capture()``)
    with no bound.  Now the read is waited for read_timeout_s, the capture is abandoned
    (released once the read returns) and the device can be reopened."""
    stuck, good = HangingCapture(), FakeCapture([(True, np.full((H, W), 90, np.uint8))])
    captures = iter([stuck, good])
    cam = VideoCamera(4, capture_factory=lambda s: next(captures), retries=3, read_timeout_s=0.2)
    t0 = time.monotonic()
    with pytest.raises(CameraLostError) as e:
        cam.read()
    assert time.monotonic() - t0 < 0.2 + 0.5  # one timeout, no retries of a read still in progress
    assert str(e.value) == ("video source 4: VideoCapture.read did not return within read_timeout_s = 0.2 s; "
                            "the capture was abandoned")
    assert not stuck.released.is_set()  # (never released under a read that is still running)
    stuck.go.set()
    assert stuck.released.wait(2.0)  # released once its read returned
    cam.reconnect()
    assert int(cam.read().max()) == 90
    with pytest.raises(ValueError, match="read_timeout_s must be > 0 seconds"):
        VideoCamera(0, capture_factory=lambda s: good, read_timeout_s=0)


class Odd(FakeCapture):
    def __init__(self, answer):
        super().__init__([])
        self.answer = answer

    def read(self):
        self.reads += 1
        if isinstance(self.answer, BaseException):
            raise self.answer
        return self.answer


@pytest.mark.parametrize("answer,why", [
    (None, "VideoCapture.read returned NoneType, not (ok, frame)"),
    ((True, np.zeros((0, 0, 3), np.uint8)), r"VideoCapture.read returned an empty frame ((0, 0, 3))"),
    ((True, None), "VideoCapture.read returned no frame"),
    (RuntimeError("backend failure\n  at line 3 of the driver"), "VideoCapture.read raised RuntimeError: backend failure"),
], ids=["None", "empty frame", "no frame", "raises"])
def test_a_camera_that_returns_nothing_is_one_clear_line(answer, why):
    """A read that returned None (no pair) or raised something other than cv2.error
    used to escape as a traceback; an empty frame was a conversion error, not a lost camera."""
    fake = Odd(answer)
    cam = VideoCamera("usb", capture_factory=lambda s: fake, retries=1)
    with pytest.raises(CameraLostError) as e:
        cam.read()
    assert str(e.value) == f"source 'usb': no usable frame after 2 attempts: {why}" and fake.reads == 2


def test_camera_that_does_not_open():
    with pytest.raises(CameraError, match="could not open"):
        VideoCamera(7, capture_factory=lambda s: FakeCapture([], opened=False))
    with pytest.raises(CameraError, match="could not open"):
        VideoCamera("/nonexistent/video.avi")


def test_image_sequence_camera(tmp_path, rng):
    frames = [rng.integers(1, 256, (H, W), dtype=np.uint8) for _ in range(3)]
    for name, f in zip(["b.png", "a.png", "c.png"], frames):
        cv2.imwrite(str(tmp_path / name), f)
    (tmp_path / "notes.txt").write_text("not an image")
    cam = ImageSequenceCamera(tmp_path, image_shape=(H, W), loop=True)
    order = [frames[1], frames[0], frames[2]]  # sorted by name
    for f in order + order[:1]:
        np.testing.assert_array_equal(cam.read(), f)
    cam = ImageSequenceCamera(str(tmp_path / "*.png"), image_shape=(H, W), loop=False)
    for f in order:
        np.testing.assert_array_equal(cam.read(), f)
    with pytest.raises(CameraError, match="exhausted after 3"):
        cam.read()


def test_image_sequence_skips_bad_files_within_the_retry_budget(tmp_path, rng):
    good = rng.integers(1, 256, (H, W), dtype=np.uint8)
    (tmp_path / "0.png").write_bytes(b"garbage, not a PNG")
    cv2.imwrite(str(tmp_path / "1.png"), np.zeros((H, W), np.uint8))
    cv2.imwrite(str(tmp_path / "2.png"), good)
    np.testing.assert_array_equal(ImageSequenceCamera(tmp_path, retries=2, loop=False).read(), good)
    with pytest.raises(CameraError, match="2 attempts: black frame"):
        ImageSequenceCamera(tmp_path, retries=1, loop=False).read()
    with pytest.raises(CameraError, match="no image files"):
        ImageSequenceCamera(tmp_path / "missing")
