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


def test_read_image_decodes_as_opencv_and_refuses_deep_images(tmp_path, rng):
    """Pillow's decoding: RGB and grey PNGs equal to OpenCV's, a palette PNG expanded to RGB, alpha dropped, a
    16-bit PNG refused in one line naming the file."""
    import pytest

    from bench.dataset import read_image
    from bench.errors import ConfigError

    rgb = rng.integers(0, 256, (30, 40, 3)).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "rgb.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert np.array_equal(read_image(tmp_path / "rgb.png"), rgb)
    cv2.imwrite(str(tmp_path / "grey.png"), rgb[..., 0])
    assert np.array_equal(read_image(tmp_path / "grey.png"), rgb[..., 0])
    Image.fromarray(np.dstack([rgb, np.full((30, 40), 7, np.uint8)])).save(tmp_path / "rgba.png")
    assert np.array_equal(read_image(tmp_path / "rgba.png"), rgb)
    Image.fromarray(rgb).quantize(16).save(tmp_path / "palette.png")
    pal = read_image(tmp_path / "palette.png")
    assert pal.shape == (30, 40, 3) and np.array_equal(pal, cv2.cvtColor(cv2.imread(str(tmp_path / "palette.png")),
                                                                         cv2.COLOR_BGR2RGB))
    cv2.imwrite(str(tmp_path / "deep.png"), rng.integers(0, 65536, (30, 40)).astype(np.uint16))
    with pytest.raises(ConfigError, match=r"deep.png: <file>: expected an 8-bit image, got Pillow mode 'I;16'"):
        read_image(tmp_path / "deep.png")


def test_corrupt_or_deep_png_refused_before_decoding(tmp_path, rng):
    """check_image_file: every single-bit flip in a PNG's compressed data fails its chunk's CRC (Pillow's decoder
    alone would decode some of them to wrong pixels), and a 16-bit colour PNG (which Pillow decodes to 8 bits) is
    refused from its header, each in one line naming the file."""
    import pytest

    from bench.errors import ConfigError

    img = cv2.GaussianBlur(rng.integers(0, 256, (40, 50, 3)).astype(np.uint8), (5, 5), 1.0)
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), img)
    check_image_file(good)
    data = good.read_bytes()
    start = data.index(b"IDAT") + 4
    length = int.from_bytes(data[start - 8:start - 4], "big")
    for k, pos in enumerate(rng.integers(start, start + length, 40)):
        bad = tmp_path / f"flip{k}.png"
        b = bytearray(data)
        b[pos] ^= 1 << int(rng.integers(8))
        bad.write_bytes(bytes(b))
        with pytest.raises(ConfigError, match=rf"flip{k}.png: <file>: PNG file corrupt: .*checksum"):
            check_image_file(bad)
    deep = tmp_path / "deep.png"
    cv2.imwrite(str(deep), (img.astype(np.uint16) * 257))
    with pytest.raises(ConfigError, match=r"deep.png: <file>: expected an 8-bit image, got a PNG of 16 bits"):
        check_image_file(deep)
