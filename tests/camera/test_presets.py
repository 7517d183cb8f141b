"""Camera presets transcribed from Tables 3, 9 and 15."""

import numpy as np
import pytest

from bench.camera.heikkila import heikkila_of
from bench.camera.presets import load_camera_spec, load_preset, preset_names, preset_path
from bench.errors import ConfigError


def test_known_presets_load_with_the_table_values():
    assert preset_names() == ["air_webcam", "underwater_in_air", "underwater_in_water"]
    web = load_preset("air_webcam")  # Table 3 average
    assert np.array_equal(web.K, [[975.3, 0, 329.3], [0, 975.3, 236.9], [0, 0, 1]])
    assert not np.any(web.dist) and web.model == "pinhole" and web.size == (640, 480)
    for name, row in [("underwater_in_air", (1.061, 510.06, 298.45, 229.20, 1.38e-2, 1.45e-3, 9.20e-5, 2.28e-4)),
                      ("underwater_in_water", (1.064, 662.6, 299.24, 239.45, 4.36e-3, 7.04e-4, 6.86e-4, 6.62e-4))]:
        cam = load_preset(name)
        h = heikkila_of(cam)
        got = (h.s_u, h.f_px, h.u0, h.v0, h.k1 * 1e-6, h.k2 * 1e-12, h.p1 * 1e-3, h.p2 * 1e-3)
        assert got == pytest.approx(row, rel=1e-12)
        assert cam.model == "heikkila" and cam.size == (640, 480) and cam.check_invertible() > 0


def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ValueError, match="unknown 'webcam' .known: air_webcam, underwater_in_air, underwater_in_water"):
        load_preset("webcam")


def test_bad_spec_files(tmp_path):
    good = preset_path("underwater_in_air").read_text()
    cases = [
        (good.replace("f_px: 510.06", "f_px: -510.06"), "heikkila_eq75.f_px: must be > 0"),
        (good.replace("f_px: 510.06", "f_px: .nan"), "heikkila_eq75.f_px: must be finite"),
        (good.replace("f_px: 510.06", "f_mm: 5.1"), "heikkila_eq75.f_mm: unknown key"),
        (good.replace("  k2_per_mm4: 1.45e-3\n", ""), "heikkila_eq75.k2_per_mm4: missing"),
        (good.replace("image_width_px: 640", "image_width_px: 640.5"), "image_width_px: expected int, got float 640.5"),
        (good + "lens: wide\n", "lens: unknown key"),
        (good.replace("k1_per_mm2: 1.38e-2", "k1_per_mm2: -0.2"), "heikkila_eq75: .*distortion"),
        ("- a\n- b\n", "<top>: expected a mapping"),
    ]
    web = preset_path("air_webcam").read_text()
    cases += [(web.replace("theta_deg: 90.0", "theta_deg: 1.5708"), "theta_deg: skew angle"),
              (web.replace("distortion: none", "distortion: barrel"), "distortion: expected none, got 'barrel'")]
    for text, message in cases:
        path = tmp_path / "cam.yaml"
        path.write_text(text)
        with pytest.raises(ConfigError, match=message) as info:
            load_camera_spec(path)
        assert "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="<file>: not found"):
        load_camera_spec(tmp_path / "none.yaml")
