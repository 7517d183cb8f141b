"""The documentation: the README is short and links every guide, links resolve, docs/reference.md is what the code
says, the README's results rows are docs/results.md's, and the metric declarations can catch a drift."""

import importlib.util
import re
from pathlib import Path

import pytest

from bench.scenario.metrics import METRICS, PLACEHOLDERS, check_metrics
from bench.scenario.runner import KINDS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _tool(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "tools" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set:
    return {_slug(m.group(1)) for m in re.finditer(r"(?m)^#{1,6} (.+)$", path.read_text())}


def test_readme_is_short_and_starts_with_the_two_commands():
    lines = README.read_text().splitlines()
    assert len(lines) <= 250
    head = "\n".join(lines[:6])
    assert "make demo" in head and "make test" in head


def test_readme_links_every_guide():
    linked = set(LINK.findall(README.read_text()))
    missing = [p.name for p in sorted(DOCS.glob("*.md")) if f"docs/{p.name}" not in linked]
    assert not missing, f"README.md does not link {missing}"


@pytest.mark.parametrize("page", [README, *sorted(DOCS.glob("*.md"))], ids=lambda p: p.name)
def test_relative_links_resolve(page):
    bad = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(target)
    assert not bad, f"{page.name}: broken links {bad}"


def test_readme_results_rows_are_quoted_from_results_md():
    text = README.read_text()
    section = text[text.index("## Results"):text.index("\n## ", text.index("## Results") + 1)]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| what ")]
    results = (DOCS / "results.md").read_text().splitlines()
    assert rows and all(r in results for r in rows), [r for r in rows if r not in results]


def test_benchmark_block_has_its_markers():
    text = (DOCS / "benchmarks.md").read_text()
    assert text.count("<!-- benchmark:begin -->") == 1 and text.count("<!-- benchmark:end -->") == 1


def test_reference_is_current():
    gen = _tool("gen_reference")
    assert (DOCS / "reference.md").read_text() == gen.render(), "docs/reference.md is out of date: run make docs"


def test_every_kind_declares_its_metrics():
    assert set(METRICS) == set(KINDS)
    for kind, declared in METRICS.items():
        names = [m.name for m in declared]
        assert len(names) == len(set(names)), kind
        for m in declared:
            assert m.unit and m.description, (kind, m.name)
            assert set(re.findall(r"<([a-z0-9]+)>", m.name)) <= set(PLACEHOLDERS), (kind, m.name)


def test_check_metrics_names_what_is_undeclared_and_what_is_missing():
    written = ["base_pos_err_mm", "base_rot_err_deg", "brand_new_metric_mm"]
    undeclared, missing = check_metrics("in_situ", written)
    assert undeclared == ["brand_new_metric_mm"]
    assert "valve_tool_err_mm" in missing and "base_pos_err_mm" not in missing
    assert "base_pos_bound_mm" not in missing  # conditional (bound.enabled): not required
    # placeholders match their values and nothing else
    assert check_metrics("xy_table", ["lms_ratio_err_x_mm_at_100"])[0] == []
    assert check_metrics("xy_table", ["lms_ratio_err_w_mm_at_100"])[0] == ["lms_ratio_err_w_mm_at_100"]
    assert check_metrics("camera_calibration", ["water_err_k1_per_mm2", "air_err_fx_px"])[0] == []
    assert check_metrics("camera_calibration", ["sea_err_fx_px"])[0] == ["sea_err_fx_px"]
