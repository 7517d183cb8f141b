"""The repository itself: the real data the tests read is in it, with its provenance; no machine's absolute path.

A clone on another machine (CI) must run the same tests: data read from outside the repository makes a test skip or
fail there, and an absolute path (under ``/work``, ``/home``, ...) names one machine's layout.
"""

import hashlib
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WEBCAM = ROOT / "tests" / "data" / "real_webcam_chessboard"
#: Top-level folders of a user's or a build machine's files: a path under one of them is one machine's layout.
MACHINE_ROOTS = ("work", "home", "root", "Users", "mnt", "media", "srv", "scratch", "data", "workspace", "builds",
                 "github", "opt")
#: Top-level folders of the operating system that code may name on purpose (``/tmp``, ``/dev/null``, ``/proc``).
SYSTEM_ROOTS = ("tmp", "dev", "proc", "usr", "etc", "sys", "bin", "var", "run", "lib")
#: A path of at least two components, starting after a quote, backtick, parenthesis, ``=``, or white space (not a
#: URL's path nor a relative ``a/b/c``).
_ABS_PATH = re.compile(r"""(?:^|[\s"'`(=\[])/([A-Za-z0-9_.-]+)/[A-Za-z0-9_.-]""")
_TEXT_SUFFIXES = (".py", ".md", ".yaml", ".yml", ".toml", ".sh", ".cfg", ".txt", ".json", ".csv", "")


def tracked_files() -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [ROOT / p for p in out.decode().split("\0") if p]


def absolute_paths(text: str, exists=lambda top: Path("/", top).is_dir()) -> list[str]:
    """The absolute machine paths in ``text``: under one of :data:`MACHINE_ROOTS`, or under any other top-level
    folder that exists on this machine, except the operating system's (:data:`SYSTEM_ROOTS`)."""
    hits = []
    for m in _ABS_PATH.finditer(text):
        top = m.group(1)
        if top in SYSTEM_ROOTS:
            continue
        if top in MACHINE_ROOTS or exists(top):
            line = text[: m.start(1)].count("\n") + 1
            end = text.find("\n", m.start(1))
            hits.append(f"line {line}: /{text[m.start(1): end if end >= 0 else None][:60]}")
    return hits


def _abs(*parts: str) -> str:
    """An absolute path built at run time, so that this file holds none (it is checked too)."""
    return "/" + "/".join(parts)


def test_absolute_path_finder():
    none = lambda top: False  # noqa: E731 - only the fixed lists decide
    shared = _abs("work", "shared", "data")
    assert absolute_paths(f'p = Path("{shared}")', none) == [f'line 1: {shared}")']
    photo = _abs("home", "ann", "photos", "x.jpg")
    assert absolute_paths(f"see\n  {photo}", none) == [f"line 2: {photo}"]
    assert absolute_paths(f"``{_abs('root', '.cache', 'x')}``", none)
    assert absolute_paths(f"({_abs('Users', 'bob', 'a')})", none)
    # the operating system's folders, URLs, relative paths, rerun entity paths under a folder that does not exist
    assert absolute_paths('open("/dev/null"); "/tmp/x/y"; "/proc/self/fd"', none) == []
    assert absolute_paths("https://github.com/firiceguo/VisualOdometryUI", none) == []
    assert absolute_paths("tests/data/real_webcam_chessboard and ../shared/seed/x.txt", none) == []
    assert absolute_paths('"/world/base/survey_true"', none) == []
    assert absolute_paths('"/world/base/survey_true"', lambda top: top == "world") != []


def test_no_absolute_machine_path_in_tracked_files():
    found = []
    for path in tracked_files():
        if path.suffix not in _TEXT_SUFFIXES or not path.is_file():
            continue
        try:
            text = path.read_text()
        except UnicodeDecodeError:
            continue
        found += [f"{path.relative_to(ROOT)}: {hit}" for hit in absolute_paths(text)]
    assert not found, "absolute machine paths (a clone elsewhere has none of them):\n" + "\n".join(found[:20])


def provenance_checksums() -> dict:
    rows = re.findall(r"^\| (\S+\.jpg) \| ([0-9a-f]{64}) \|$", (WEBCAM / "PROVENANCE.md").read_text(), re.M)
    return dict(rows)


def test_real_webcam_photos_are_in_the_repository_as_documented():
    assert (WEBCAM / "PROVENANCE.md").is_file(), f"{WEBCAM}: the real webcam photos and their PROVENANCE.md"
    sums = provenance_checksums()
    assert len(sums) == 19 and "left10.jpg" in sums and "legt10.jpg" not in sums
    present = sorted(p.name for p in WEBCAM.glob("*.jpg"))
    assert present == sorted(sums), f"{WEBCAM}: photos present {present}, PROVENANCE.md lists {sorted(sums)}"
    for name, digest in sums.items():
        assert hashlib.sha256((WEBCAM / name).read_bytes()).hexdigest() == digest, f"{name} differs from its source"
    tracked = {p.relative_to(ROOT).as_posix() for p in tracked_files()}
    missing = [n for n in sums if f"tests/data/real_webcam_chessboard/{n}" not in tracked]
    assert not missing, f"photos not committed (a clone would lack them): {missing}"


@pytest.mark.parametrize("test_file", ["tests/camera/test_calibration.py", "tests/camera/test_corners.py"])
def test_real_data_tests_never_skip(test_file):
    """A test whose data is missing fails: no skip marker around the real photos."""
    text = (ROOT / test_file).read_text()
    assert "real_webcam_chessboard" in text
    assert "skipif" not in text and "pytest.skip" not in text and "importorskip" not in text
