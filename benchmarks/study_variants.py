"""Run some rows of a training study: the same parts (OUT/parts) as `moseg study NAME`, fewer variants.

    python benchmarks/study_variants.py NAME OUT "LABEL|LABEL|..." [--budget cpu|full]

NAME is a training study (losses, networks, weak-supervision, embedding-dim, depth), LABEL a row of its
table. The parts are keyed exactly as the full study keys them, so a later `moseg study NAME --out OUT`
reuses them and trains only the other rows. One thread; data from $MOSEG_DATA (or ../shared/data).
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name")
    parser.add_argument("out", type=Path)
    parser.add_argument("labels", help="rows to run, separated by '|'")
    parser.add_argument("--budget", default="cpu", choices=("cpu", "full"))
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")

    from mosegpipe.studies import get_study
    from mosegpipe.studies.common import StudyRequest
    from mosegpipe.studies.training import TRAINING_STUDIES, run_training_study

    spec = TRAINING_STUDIES[args.name][2]
    wanted = args.labels.split("|")
    unknown = sorted(set(wanted) - {v.label for v in spec.variants})
    if unknown:
        raise SystemExit(f"unknown rows {unknown}; choose from {[v.label for v in spec.variants]}")
    spec = dataclasses.replace(spec, variants=tuple(v for v in spec.variants if v.label in wanted))
    root = Path(os.environ.get("MOSEG_DATA", "../shared/data"))
    req = StudyRequest(out_dir=args.out, budget=args.budget, data_root=root, progress=print)
    print(run_training_study(spec, get_study(args.name), req).table)


if __name__ == "__main__":
    main()
