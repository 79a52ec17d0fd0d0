"""Run some configurations of `moseg study lce-curve` (the same parts, so the full study reuses them).

python benchmarks/lce_curve_configs.py OUT NAME[,NAME...] [--budget cpu|full]
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("names", help="comma-separated configuration names (studies.lce.CURVE_CONFIGS)")
    parser.add_argument("--budget", default="cpu", choices=("cpu", "full"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    from mosegpipe.runtime import set_threads
    from mosegpipe.studies import get_study
    from mosegpipe.studies.common import StudyRequest
    from mosegpipe.studies.lce import CURVE_CONFIGS, run_lce_curve

    set_threads(1)
    wanted = args.names.split(",")
    configs = [cc for cc in CURVE_CONFIGS if cc.name in wanted]
    if len(configs) != len(wanted):
        raise SystemExit(f"unknown configurations; choose from {[cc.name for cc in CURVE_CONFIGS]}")
    req = StudyRequest(out_dir=args.out, budget=args.budget, progress=print)
    print(run_lce_curve(get_study("lce-curve"), req, configs=configs).table)


if __name__ == "__main__":
    main()
