"""``make docs``: write ``docs/reference.md``, every scenario key and every ``result.json`` metric, from the code.

For each scenario kind (``bench.scenario.runner.KINDS``): the keys of its pydantic model (``Scenario`` of the kind's
module) with type, default and declared constraints (ranges, lengths, choices), the unit that the key's name carries,
the meaning (the field's ``description``, else the comments of the kind's files in ``scenarios/``), and what loading
refuses, found by asking it (a negative number, an unknown word, an empty list through the model and the kind's
``validate()``); then the metrics ``bench.scenario.metrics.METRICS`` declares. Nothing is typed by hand, so
``tests/test_docs.py`` can check that the committed file equals this script's output.

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

from bench.config import constraint_text, default_of, leaves, type_text, unit_of  # noqa: E402
from bench.errors import BenchError  # noqa: E402
from bench.fileio import atomic_write_text  # noqa: E402
from bench.scenario.metrics import METRICS, PLACEHOLDERS  # noqa: E402
from bench.scenario.runner import KINDS, check_scenario, kind_module  # noqa: E402

#: the probe value per type name (what loading says to it goes into the reference)
PROBES = {"int": -1, "float": -1.0, "str": "no-such-value", "list": []}
_KEY = re.compile(r"^(\s*)([A-Za-z0-9_]+):(.*)$")


def probe_of(field):
    """The probe for a field's type (``None``: not probed, e.g. a bool)."""
    text = type_text(field.annotation).removesuffix(" or null")
    kind = "list" if text.startswith("list") else "str" if text.startswith(("one of", "str")) or " or " in text \
        else text
    return copy.deepcopy(PROBES.get(kind))


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


def refusals(raw: dict, source: Path, keys) -> dict:
    """``{key: (probe, message)}``: what loading (the model, then the kind's ``validate()``) says to a probe value at
    each key of a valid scenario ``raw``."""
    out = {}
    for key, field in keys:
        value = probe_of(field)
        if value is None:
            continue
        node = probe = copy.deepcopy(raw)
        *path, leaf = key.split(".")
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = value
        try:
            check_scenario(probe, source)
        except BenchError as exc:
            if key == getattr(exc, "field", ""):
                out[key] = (value, getattr(exc, "problem", str(exc)))
        except Exception as exc:  # noqa: BLE001 - a check that crashes is reported, not hidden
            out[key] = (value, f"loading raised {type(exc).__name__} (not a one-line error)")
    return out


def _cell(v) -> str:
    if v is ...:
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
    keys = list(leaves(module.Scenario))
    refused = refusals(yaml.safe_load(files[0].read_text()), files[0], keys) if files else {}
    doc = (module.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ").replace("``", "`")
    lines = [f"## `{kind}`", "", f"`bench/scenario/{kind}.py`: {_esc(doc)}", ""]
    lines.append("Scenario files: " + (", ".join(f"`scenarios/{p.name}`" for p in files) or "none") + ".")
    lines += ["", "### Keys", "", "| key | type | default | unit | constraints | meaning (the model's description, "
              "else the scenario files' comments) | refused (probe: message) |", "|---|---|---|---|---|---|---|"]
    sections = set()
    for key, field in keys:
        section = key.rsplit(".", 1)[0] if "." in key else ""
        if section and section not in sections:
            sections.add(section)
            doc = " ".join((module.Scenario.model_fields[section.split(".")[0]].annotation.__doc__ or "").split())
            text, src = comments.get(section, (doc, ""))
            if text:
                lines.append(f"| `{section}.*` | section | | | | {_esc(text)}{f' ({src})' if src else ''} | |")
        meaning = (field.description, "") if field.description else comments.get(key)
        meaning = f"{_esc(meaning[0])}{f' ({meaning[1]})' if meaning[1] else ''}" if meaning else ""
        ref = refused.get(key)
        ref = f"`{ref[0]!r}`: {_esc(ref[1])}" if ref else ""
        unit = unit_of(key)
        lines.append(f"| `{key}` | {_esc(type_text(field.annotation))} | {_esc(_cell(default_of(field)))} | {unit} | "
                     f"{_esc(constraint_text(field, unit))} | {meaning} | {ref} |")
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
             "*Generated by `make docs` (`tools/gen_reference.py`) from each kind's pydantic model (`Scenario`) and "
             "`validate()`, the comments of `scenarios/*.yaml` and `bench/scenario/metrics.py`; do not edit. "
             "`tests/test_docs.py` checks that this file is current, and the kinds' smoke tests that a run writes "
             "exactly the metrics declared here.*", "",
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
    atomic_write_text(out, text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
