"""The bench side: MuJoCo scenes, the TA-40 model, rendering, optics, encoders and dataset writing.

Headless rendering: ``MUJOCO_GL=egl`` is set here, before any submodule imports MuJoCo, unless the user chose a
backend (Mesa's software EGL; Debian packages ``libegl1 libgl1-mesa-dri``).
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
