import numpy as np
import pytest

from bench.dataset import DatasetWriter, load_dataset
from bench.errors import ConfigError


def _write(root, rng, n=3, **kw):
    imgs = rng.integers(0, 256, size=(n, 24, 32, 3), dtype=np.uint8)
    q = rng.uniform(-1.0, 1.5, size=(n, 6))
    with DatasetWriter(root, kind="in_situ", name="t", created_by="test", **kw) as w:
        for i in range(n):
            w.add_view(f"v{i}", imgs[i], q=q[i], role="reference" if i == 0 else "surround")
        w.write_tracker(["a", "b"], rng.normal(size=(2, 3)), q[:2])
    return imgs, q


def test_round_trip_is_lossless_and_si(tmp_path, rng):
    imgs, q = _write(tmp_path / "ds", rng)
    ds = load_dataset(tmp_path / "ds")
    assert ds.kind == "in_situ" and [v.name for v in ds.views] == ["v0", "v1", "v2"]
    assert ds.views[0].role == "reference"
    assert np.abs(ds.joint_readings() - q).max() < 1e-12  # repr() of float64: exact round trip
    for v, img in zip(ds.views, imgs, strict=True):
        assert np.array_equal(v.image(expected_size=(32, 24)), img)  # PNG: lossless, RGB order kept
    assert ds.tracker["p"].shape == (2, 3) and ds.tracker["point"] == ["a", "b"]
    assert not (tmp_path / "ds" / "truth").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]  # no temporary folder left


def test_failed_write_leaves_nothing(tmp_path, rng):
    with pytest.raises(RuntimeError):
        with DatasetWriter(tmp_path / "ds", kind="in_situ") as w:
            w.add_view("v0", np.zeros((4, 4, 3), np.uint8), q=np.zeros(6))
            raise RuntimeError("renderer crashed")
    assert list(tmp_path.iterdir()) == []


def test_existing_dataset_needs_overwrite_and_is_replaced_whole(tmp_path, rng):
    _write(tmp_path / "ds", rng)
    with pytest.raises(ConfigError, match="already exists"):
        DatasetWriter(tmp_path / "ds", kind="in_situ")
    _write(tmp_path / "ds", rng, n=2, overwrite=True)
    assert len(load_dataset(tmp_path / "ds").views) == 2
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


@pytest.mark.parametrize("edit, match", [
    (lambda r: (r / "manifest.yaml").unlink(), "manifest.yaml: <file>: not found"),
    (lambda r: (r / "manifest.yaml").write_text("views: [\n"), "not valid YAML"),
    (lambda r: (r / "manifest.yaml").write_text((r / "manifest.yaml").read_text() + "colour: red\n"),
     "colour: unknown key"),
    (lambda r: (r / "joints.csv").write_text((r / "joints.csv").read_text().replace("q3_deg", "q3")),
     "joints.csv: q3_deg: missing column"),
    (lambda r: (r / "joints.csv").write_text((r / "joints.csv").read_text() + "v9,1,2,3,4,5,6\n"),
     "joints.csv: v9: readings for a view that the manifest does not list"),
    (lambda r: (r / "joints.csv").write_text(
        "\n".join(ln if not ln.startswith("v1,") else "v1,nan,0,0,0,0,0" for ln in
                  (r / "joints.csv").read_text().splitlines())), r"joints.csv: line 3 \(v1\).q1_deg: NaN"),
    (lambda r: (r / "joints.csv").write_text(
        "\n".join(ln if not ln.startswith("v1,") else "v1,abc,0,0,0,0,0" for ln in
                  (r / "joints.csv").read_text().splitlines())), "not a number: 'abc'"),
    (lambda r: (r / "joints.csv").write_text(
        "\n".join(ln if not ln.startswith("v1,") else "v1,1000,0,0,0,0,0" for ln in
                  (r / "joints.csv").read_text().splitlines())), "not degrees"),
    (lambda r: (r / "tracker.csv").write_text("point,x_mm\n"), "tracker.csv: y_mm: missing column"),
])
def test_bad_files_are_one_line_errors(tmp_path, rng, edit, match):
    _write(tmp_path / "ds", rng)
    edit(tmp_path / "ds")
    with pytest.raises(ConfigError, match=match) as info:
        load_dataset(tmp_path / "ds")
    assert "\n" not in str(info.value)


def test_bad_images_are_named(tmp_path, rng):
    _write(tmp_path / "ds", rng)
    ds = load_dataset(tmp_path / "ds")
    (tmp_path / "ds" / "images" / "v1.png").write_bytes(b"\x89PNG truncated")
    (tmp_path / "ds" / "images" / "v2.png").unlink()
    with pytest.raises(ConfigError, match="v1.png: <header>: image of view 'v1': not a PNG file"):
        ds.view("v1").image()
    with pytest.raises(ConfigError, match="v2.png: <file>: image of view 'v2' not found"):
        ds.view("v2").image()
    with pytest.raises(ConfigError, match="image is 32x24, the camera file says 640x480"):
        ds.view("v0").image(expected_size=(640, 480))
    with pytest.raises(ConfigError, match="no view named 'v7'"):
        ds.view("v7")


def test_radians_in_degree_columns_are_refused(tmp_path, rng):
    with DatasetWriter(tmp_path / "rad", kind="in_situ") as w:
        for i in range(4):  # a writer that forgot the conversion: degree columns holding radians
            w.add_view(f"v{i}", np.zeros((4, 4, 3), np.uint8), q=np.deg2rad(rng.uniform(-1.5, 1.5, 6)))
    with pytest.raises(ConfigError, match=r"joints.csv: q1_deg \.\.\. q6_deg: every reading .* radians written"):
        load_dataset(tmp_path / "rad")


def test_frame_of_readings_only(tmp_path, rng):
    """A taught tool pose: joint readings without an image; asking for its image is a one-line error."""
    q = rng.uniform(-1.0, 1.5, size=6)
    with DatasetWriter(tmp_path / "ds", kind="in_situ") as w:
        w.add_view("v0", np.zeros((4, 4, 3), np.uint8), q=q, role="reference")
        w.add_view("teach", None, q=q, role="task")
        with pytest.raises(ValueError, match="needs an image or readings"):
            w.add_view("empty", None)
    ds = load_dataset(tmp_path / "ds")
    teach = ds.view("teach")
    assert teach.image_path is None and teach.role == "task" and np.abs(teach.q - q).max() < 1e-12
    with pytest.raises(ConfigError, match="teach: image: this view is a frame of readings only"):
        teach.image()
    man = (tmp_path / "ds" / "manifest.yaml").read_text()
    (tmp_path / "ds" / "joints.csv").write_text("view," + ",".join(f"q{i}_deg" for i in range(1, 7)) + "\n"
                                                + "v0" + ",0" * 6 + "\n")
    with pytest.raises(ConfigError, match=r"views\[1\].image: missing \(a view needs an image or readings\)"):
        load_dataset(tmp_path / "ds")
    (tmp_path / "ds" / "manifest.yaml").write_text(man.replace("name: teach", "name: teach\n  image: 7"))
    with pytest.raises(ConfigError, match=r"views\[1\].image: expected a file name"):
        load_dataset(tmp_path / "ds")


def test_photo_files_lists_every_photo_suffix_in_any_case(tmp_path):
    """The one listing of a plain folder of photos (the calibration's, the dataset initialiser's and the replica's):
    .png / .jpg / .jpeg in any case, sorted by name; other files and folders left out."""
    from bench.dataset import photo_files

    for name in ("b.JPG", "a.png", "c.jpeg", "notes.txt", "d.tif"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "e.png").mkdir()
    assert [p.name for p in photo_files(tmp_path)] == ["a.png", "b.JPG", "c.jpeg"]
