"""Wall time of one registration against two run at once from two Python threads.

Run from a venv with the wheel (scripts/python-env):
    .venv/bin/python benches/py_threads.py [--repeats 5]

Prints medians over the repeats and the ratio (two at once) / (one): 2.0 would mean the calls
ran one after the other (the GIL held); 1.0 that the second was free. With `threads=0` each call
already uses every core, so the gain comes from what one call leaves idle; with `threads=1` per
call, two calls on two cores should take about as long as one.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

import sdfreg

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "crates/sdfreg-py/tests"))
from conftest import paper_pair  # noqa: E402


def one(pair, threads: int) -> float:
    source, target, _ = pair
    start = time.perf_counter()
    sdfreg.register(source, target, threads=threads)
    return time.perf_counter() - start


def two_at_once(pairs, threads: int) -> float:
    workers = [
        threading.Thread(target=sdfreg.register, args=(s, t), kwargs={"threads": threads})
        for s, t, _ in pairs
    ]
    start = time.perf_counter()
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    pairs = [paper_pair(31), paper_pair(32)]
    one(pairs[0], 0)  # warm-up
    print(f"sdfreg {sdfreg.__version__}: 1024-point paper pairs, median of {args.repeats}")
    print("| threads per call | one call (s) | two calls at once (s) | ratio |")
    print("|---|---|---|---|")
    for threads in (0, 1):
        singles, doubles = [], []
        for _ in range(args.repeats):
            singles.append(one(pairs[0], threads))
            doubles.append(two_at_once(pairs, threads))
        a, b = statistics.median(singles), statistics.median(doubles)
        label = "all cores (0)" if threads == 0 else str(threads)
        print(f"| {label} | {a:.3f} | {b:.3f} | {b / a:.2f} |")


if __name__ == "__main__":
    main()
