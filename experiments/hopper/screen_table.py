"""Gather the scores of a screen's runs into one CSV: every evaluation of every ``<OUT>/<tag>_file<S>*/scores.csv``.

    python experiments/hopper/screen_table.py <OUT> > experiments/hopper/q_weight_screen.csv

The folder name before ``_file`` is the screen's tag (``experiments/hopper/q_weight_screen.sh``), the digit after it
the collection's ``SEED``.
"""

from __future__ import annotations

import argparse
import csv
import pathlib
import re
import sys

from sb3_pola.grid.rows import read_rows

NAME = re.compile(r"^(?P<tag>.+)_file(?P<file>\d+)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=pathlib.Path, help="the screen's output folder")
    args = parser.parse_args()
    writer = csv.writer(sys.stdout, lineterminator="\n")
    writer.writerow(["tag", "file", "dataset", "seed", "step", "score", "score_std", "eval_episodes"])
    for path in sorted(args.out.glob("*/scores.csv")):
        match = NAME.match(path.parent.name)
        if match is None:
            continue
        for row in read_rows(path):
            fields = [row[k] for k in ("dataset", "seed", "step", "score", "score_std", "eval_episodes")]
            writer.writerow([match["tag"], match["file"], *fields])


if __name__ == "__main__":
    main()
