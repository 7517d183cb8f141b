"""Image files read through Pillow's header reader: what every image library reads is read here too."""

import cv2
import numpy as np
from PIL import Image

from bench.dataset import check_image_file, image_header, load_dataset
from bench.dataset_init import init_dataset


def _jpeg_with_fill_byte(rng) -> tuple[bytes, bytes]:
    """A JPEG, and the same JPEG with a 0xFF fill byte before its SOF0 marker (JPEG allows any number of them)."""
    img = cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3)).astype(np.uint8), (5, 5), 1.0)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    plain = buf.tobytes()
    sof = plain.index(b"\xff\xc0")
    filled = plain[:sof] + b"\xff" + plain[sof:]
    assert filled[sof:sof + 3] == b"\xff\xff\xc0"
    return plain, filled


def test_jpeg_with_a_fill_byte_before_its_frame_header_is_read(tmp_path, rng):
    plain, filled = _jpeg_with_fill_byte(rng)
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "plain.jpg").write_bytes(plain)
    (photos / "filled.jpg").write_bytes(filled)
    assert image_header(photos / "filled.jpg") == ("JPEG", 64, 48)
    check_image_file(photos / "filled.jpg", expected_size=(64, 48))

    init_dataset(tmp_path / "ds", images=photos)  # a camera-calibration dataset of the two photos
    ds = load_dataset(tmp_path / "ds")
    got = ds.view("filled").image(expected_size=(64, 48))
    assert got.shape == (48, 64, 3) and got.dtype == np.uint8
    assert np.array_equal(got, ds.view("plain").image())  # the fill byte changes nothing in the image
    with Image.open(photos / "filled.jpg") as im:  # Pillow decodes it as OpenCV does
        assert np.array_equal(np.asarray(im.convert("RGB")), got)
    bgr = cv2.imdecode(np.frombuffer(filled, np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), got)
