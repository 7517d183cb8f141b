"""Run a scenario file: validate, dispatch on its ``kind``, write ``result.json``, print a summary."""

from __future__ import annotations

import importlib
from pathlib import Path

import numpy as np

from bench.config import apply_overrides, load_yaml, parse
from bench.errors import BenchError, ConfigError
from bench.fileio import claimed_output_dir, settings_identity

# the scenario kinds, each a module of bench.scenario of the same name (imported only when a scenario of it runs)
KINDS = ("kinematic_identification", "tracker_base_frame", "in_situ", "xy_table", "camera_calibration",
         "flatport_study", "camera_replica")


def kind_module(kind: str, source="<scenario>"):
    """The module implementing a scenario ``kind`` (the model ``Scenario``, ``run``, optionally ``validate``,
    ``render``)."""
    if kind is None:
        raise ConfigError(source, "kind", f"missing (known kinds: {', '.join(KINDS)})")
    if not isinstance(kind, str) or kind not in KINDS:
        raise ConfigError(source, "kind", f"unknown scenario kind {kind!r} (known: {', '.join(KINDS)})")
    return importlib.import_module(f"bench.scenario.{kind}")


def check_scenario(raw: dict, source) -> dict:
    """A raw scenario mapping checked by its kind's model (keys, types, ranges, choices) and then by the kind's
    ``validate(cfg)`` where the module has one (what needs a robot, optics or files); the validated nested dicts,
    ``_file`` the scenario's absolute path."""
    module = kind_module(raw.get("kind"), source)
    cfg = parse(module.Scenario, raw, str(source))
    cfg["_file"] = str(Path(source).resolve())
    if hasattr(module, "validate"):  # before anything is created
        module.validate(cfg)
    return cfg


def load_scenario(path, seed=None, overrides=()) -> dict:
    """Load, override (``--set``, ``--seed``) and check a scenario (:func:`check_scenario`); paths inside it are
    resolved relative to the file."""
    path = Path(path)
    raw = apply_overrides(load_yaml(path), overrides, str(path))
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise BenchError(f"--seed: expected a non-negative integer, got {seed!r}")
        raw["seed"] = int(seed)
    return check_scenario(raw, path)


def run_identity(cfg: dict, overrides=()) -> str:
    """A run folder's identity (:func:`bench.fileio.settings_identity`): the scenario's name, the seed the run used
    (``--seed``, or the file's) and the ``--set`` overrides as given (not the file's path: a sweep moved with its
    scenario still resumes). A re-run with the same writes into the folder again; another seed or override is
    refused without ``force``, the refusal naming what differs."""
    return settings_identity({}, name=cfg["name"], seed=cfg.get("seed"), set=[str(o) for o in overrides])


def run_scenario_file(path, out=None, seed=None, overrides=(), verbose=True, quiet=False, force=False):
    """Run one scenario; returns the path of ``result.json`` (``quiet``: print nothing, e.g. in sweep workers).

    The output folder is claimed before the run (:func:`bench.fileio.claim_output_dir`, command ``run``, identity
    :func:`run_identity`: the scenario, its seed and the ``--set`` overrides): a new or empty folder, or a previous
    run of the same scenario with the same seed and overrides (re-run in place); ``force`` replaces a previous run
    (of this or another scenario, or with other settings) with a fresh one; anything else is refused, so that a run
    with another seed does not silently take the place of one's earlier result. A run that fails leaves no folder it
    created behind (and an empty folder it was given empty).
    """
    cfg = load_scenario(path, seed, overrides)
    module = kind_module(cfg["kind"])
    out_dir = Path(out) if out else Path("runs") / cfg["name"]
    with claimed_output_dir(out_dir, "run", force=force, identity=run_identity(cfg, overrides)):
        result_path = module.run(cfg, out_dir, verbose=verbose)
    if verbose:
        print(f"wrote {result_path}")
    elif not quiet:
        print(result_path)
    return result_path
