"""``make docs``: write ``docs/reference.md``, every scenario key and every ``result.json`` metric, from the code.

For each scenario kind (``bench.scenario.runner.KINDS``): the keys of its ``SCHEMA`` with type and default, the unit
that the key's name carries, the meaning from the comments of the kind's files in ``scenarios/`` (the only place the
repository documents most keys), and what the kind's ``validate()`` refuses, found by asking it (a negative number,
an unknown word, an empty list); then the metrics ``bench.scenario.metrics.METRICS`` declares. Nothing is typed by
hand, so ``tests/test_docs.py`` can check that the committed file equals this script's output.

Usage: ``python tools/gen_reference.py [--out docs/reference.md] [--check]``.
"""

from __future__ import annotations

import argparse
import copy
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import yaml  # noqa: E402

from bench.errors import BenchError  # noqa: E402
from bench.fileio import atomic_write_text  # noqa: E402
from bench.scenario.metrics import METRICS, PLACEHOLDERS  # noqa: E402
from bench.scenario.runner import KINDS, kind_module  # noqa: E402
from bench.scenario.schema import _REQUIRED, validate  # noqa: E402

# unit carried by a key's name (longest suffix first)
UNITS = (("_per_mm2", "1/mm²"), ("_per_mm4", "1/mm⁴"), ("_per_mm", "1/mm"), ("_mm", "mm"), ("_deg", "deg"),
         ("_rad", "rad"), ("_px", "px"), ("_pct", "%"), ("_m", "m"), ("_s", "s"))
PROBES = {int: -1, float: -1.0, str: "no-such-value", list: []}
_KEY = re.compile(r"^(\s*)([A-Za-z0-9_]+):(.*)$")


def unit_of(key: str) -> str:
    leaf = key.rsplit(".", 1)[-1]
    return next((u for s, u in UNITS if leaf.endswith(s)), "")


def leaves(schema: dict, prefix: str = ""):
    """``(dotted key, type, default)`` of every leaf, in the schema's order."""
    for key, spec in schema.items():
        if isinstance(spec, dict):
            yield from leaves(spec, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", spec[0], spec[1]


def yaml_comments(path: Path) -> dict:
    """``{dotted key: comment}`` from a scenario file's comments (sections included).

    A comment on a key's line documents it; a comment line of its own in the body documents the key after it; a
    comment that starts with three spaces (``#   ...``) continues the previous one (and a key whose own comment is
    such a continuation is documented by that previous comment).
    """
    out, stack, pending = {}, [], []
    last = None
    for line in path.read_text().splitlines():
        m = _KEY.match(line)
        if line.strip().startswith("#") or not m:
            text = line.split("#", 1)[1] if line.strip().startswith("#") else ""
            if text.startswith("   ") and last is not None:
                out[last] = f"{out[last]} {text.strip()}"
            elif text.strip() and stack:
                pending.append(text.strip())
            continue
        indent, key, rest = len(m.group(1)), m.group(2), m.group(3)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, key))
        dotted = ".".join(k for _, k in stack)
        raw = rest.split(" #", 1)[1] if " #" in rest else ""
        if raw.startswith("   ") and last is not None:
            out[last] = f"{out[last]} {raw.strip()}"
            out[dotted] = f"see `{last}`"
            continue
        text = " ".join(pending + ([raw.strip()] if raw.strip() else []))
        pending = []
        if text:
            out[dotted] = text
            last = dotted
    return out


def refusals(module, cfg: dict, keys) -> dict:
    """``{key: (probe, message)}``: what the kind's ``validate()`` says to a value no key accepts."""
    out = {}
    if not hasattr(module, "validate"):
        return out
    for key, kind, _ in keys:
        if kind not in PROBES:
            continue
        probe = copy.deepcopy(cfg)
        node = probe
        *path, leaf = key.split(".")
        for part in path:
            node = node[part]
        node[leaf] = PROBES[kind]
        try:
            module.validate(probe)
        except BenchError as exc:
            field = getattr(exc, "field", "")
            if key in str(field):
                out[key] = (PROBES[kind], getattr(exc, "problem", str(exc)))
        except Exception as exc:  # noqa: BLE001 - a validate() that crashes is reported, not hidden
            out[key] = (PROBES[kind], f"validate() raised {type(exc).__name__} (not a one-line error)")
    return out


def _cell(v) -> str:
    if v is _REQUIRED:
        return "*required*"
    text = yaml.safe_dump(v, default_flow_style=True, width=1000).strip()
    text = text.removesuffix("...").strip()
    return f"`{text}`" if text else "`''`"


def _esc(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def kind_section(kind: str) -> list[str]:
    module = kind_module(kind)
    files = sorted(p for p in (ROOT / "scenarios").glob("*.yaml")
                   if (yaml.safe_load(p.read_text()) or {}).get("kind") == kind)
    comments: dict = {}
    for p in files:
        for k, v in yaml_comments(p).items():
            comments.setdefault(k, (v, p.name))
    keys = list(leaves(module.SCHEMA))
    refused = {}
    if files:
        raw = yaml.safe_load(files[0].read_text())
        cfg = validate(raw, module.SCHEMA, str(files[0].relative_to(ROOT)))
        cfg["_file"] = str(files[0].relative_to(ROOT))
        refused = refusals(module, cfg, keys)
    doc = (module.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ").replace("``", "`")
    lines = [f"## `{kind}`", "", f"`bench/scenario/{KINDS[kind]}.py`: {_esc(doc)}", ""]
    lines.append("Scenario files: " + (", ".join(f"`scenarios/{p.name}`" for p in files) or "none") + ".")
    lines += ["", "### Keys", "", "| key | type | default | unit | meaning (from the scenario files' comments) | "
              "`validate()` refuses |", "|---|---|---|---|---|---|"]
    sections = set()
    for key, typ, default in keys:
        section = key.rsplit(".", 1)[0] if "." in key else ""
        if section and section not in sections:
            sections.add(section)
            if section in comments:
                text, src = comments[section]
                lines.append(f"| `{section}.*` | section | | | {_esc(text)} ({src}) | |")
        meaning = comments.get(key)
        meaning = f"{_esc(meaning[0])} ({meaning[1]})" if meaning else ""
        ref = refused.get(key)
        ref = f"`{ref[0]!r}`: {_esc(ref[1])}" if ref else ""
        lines.append(f"| `{key}` | {typ.__name__} | {_esc(_cell(default))} | {unit_of(key)} | {meaning} | {ref} |")
    lines += ["", "### Metrics", "", "| metric | unit | meaning | written when |", "|---|---|---|---|"]
    used = set()
    for m in METRICS[kind]:
        used.update(re.findall(r"<([a-z0-9]+)>", m.name))
        lines.append(f"| `{m.name}` | {m.unit} | {_esc(m.description)} | {m.when or 'always'} |")
    if used:
        lines += ["", "Placeholders: " + "; ".join(f"`<{p}>`: {PLACEHOLDERS[p][1]}" for p in sorted(used)) + "."]
    return lines + [""]


def render() -> str:
    lines = ["# Reference: scenario keys and `result.json` metrics", "",
             "*Generated by `make docs` (`tools/gen_reference.py`) from each kind's `SCHEMA` and `validate()`, the "
             "comments of `scenarios/*.yaml` and `bench/scenario/metrics.py`; do not edit. `tests/test_docs.py` "
             "checks that this file is current, and the kinds' smoke tests that a run writes exactly the metrics "
             "declared here.*", "",
             "Set a key with `bench run FILE --set KEY=VALUE` (or `bench sweep ... --param KEY=v1,v2`); an unknown or "
             "mistyped key is a one-line error. Units inside the code are SI; a key or metric carries its unit in "
             "its name. `result.json` holds `scenario`, `seed`, `metrics` (below; non-finite values are `null`), "
             "`tables`, `timings_s` and `artifacts`.", "",
             "Kinds: " + ", ".join(f"[`{k}`](#{k})" for k in KINDS) + ".", ""]
    for kind in KINDS:
        lines += kind_section(kind)
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "reference.md"))
    ap.add_argument("--check", action="store_true", help="exit 1 if the file differs from what would be written")
    args = ap.parse_args(argv)
    text, out = render(), Path(args.out)
    if args.check:
        if not out.is_file() or out.read_text() != text:
            print(f"{out} is out of date: run make docs", file=sys.stderr)
            return 1
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
