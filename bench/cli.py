"""The ``bench`` command line (see ``shared/design.md``: ``bench run SCENARIO [--out DIR] [--seed N] [--set k=v]``)."""

from __future__ import annotations

import argparse
import sys

from bench.errors import BenchError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bench", description="In-situ calibration bench for subsea manipulators.")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run one scenario and write DIR/result.json")
    run.add_argument("scenario", help="scenario YAML file")
    run.add_argument("--out", default=None, help="output folder (default runs/<scenario name>)")
    run.add_argument("--seed", type=int, default=None, help="override the scenario's seed")
    run.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scenario key (dotted path), e.g. --set monte_carlo.seeds=50")
    run.add_argument("--quiet", action="store_true", help="print only the result path")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "run":
            from bench.scenario.runner import run_scenario_file

            run_scenario_file(args.scenario, out=args.out, seed=args.seed, overrides=args.overrides,
                              verbose=not args.quiet)
        return 0
    except BenchError as exc:
        print(f"bench: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bench: interrupted", file=sys.stderr)
        return 130
