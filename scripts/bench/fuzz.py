"""Run the fuzz suite (tests/test_fuzz.py) at length: new examples for every parser, round after round, for N minutes.

    python scripts/bench/fuzz.py --minutes 30            # every parser in turn, until 30 minutes are up
    python scripts/bench/fuzz.py --minutes 5 --only glb  # one parser (a substring of its test's name)
    python scripts/bench/fuzz.py --quick                 # 5 examples of each, in one process: that it runs

Each round runs one parser's test in a pytest process of its own with
``XVIZ_FUZZ=long`` (new random examples, an example over 10 s a failure)
and ``XVIZ_FUZZ_EXAMPLES`` examples, so that a round ends by itself and
reports what it found, shrunk to its smallest input. A round that fails
stops the run: its report is printed, with the ``@reproduce_failure`` line
to paste over the test, and the script exits 1. A round that runs past
``--hang`` seconds is a hang, reported the same way.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: The fuzz tests, by the short name ``--only`` matches.
TARGETS = {
    "glb": "test_glb",
    "json": "test_json",
    "pbe": "test_pbe",
    "index": "test_log_index",
    "session": "test_session_answers_every_client_message",
    "url": "test_session_answers_every_connection_url",
    "admission": "test_admission",
    "waymo": "test_waymo_tfrecord",
    "bag": "test_ros1_bag",
    "resp": "test_resp_replies",
    "hiredis": "test_resp_replies_as_hiredis_reads_them",
}


def round_of(test: str, examples: int, hang: float) -> tuple[bool, str, float]:
    """One round of ``test`` (one or more, space-separated): whether it passed, the tail of its report, its seconds."""
    env = {**os.environ, "XVIZ_FUZZ": "long", "XVIZ_FUZZ_EXAMPLES": str(examples)}
    command = [
        sys.executable,
        "-m",
        "pytest",
        *(f"tests/test_fuzz.py::{name}" for name in test.split()),
        "-q",
        "-p",
        "no:cacheprovider",
        "-x",
        "--show-capture=no",
    ]
    started = time.monotonic()
    try:
        done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=hang)
    except subprocess.TimeoutExpired as exc:
        output = exc.stdout if isinstance(exc.stdout, str) else (exc.stdout or b"").decode(errors="replace")
        return False, f"{test}: no answer in {hang:g} s (a hang?)\n{output[-3000:]}", time.monotonic() - started
    return done.returncode == 0, (done.stdout + done.stderr)[-6000:], time.monotonic() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="how long to fuzz (default 10)")
    parser.add_argument(
        "--only",
        action="append",
        default=[],
        help="fuzz the parsers whose short name holds this (repeatable): " + ", ".join(TARGETS),
    )
    parser.add_argument("--examples", type=int, default=500, help="examples per round (default 500)")
    parser.add_argument("--hang", type=float, default=900.0, help="seconds after which a round is a hang (default 900)")
    parser.add_argument("--quick", action="store_true", help="one round of 5 examples of each parser, in one process")
    args = parser.parse_args()
    tests = [test for name, test in TARGETS.items() if not args.only or any(word in name for word in args.only)]
    if not tests:
        parser.error(f"--only matches none of {', '.join(TARGETS)}")
    examples = 5 if args.quick else args.examples
    if args.quick:
        tests = [" ".join(tests)]
    deadline = time.monotonic() + args.minutes * 60
    runs: dict[str, list[float]] = {test: [] for test in tests}
    while not any(runs.values()) or (not args.quick and time.monotonic() < deadline):
        for test in tests:
            passed, report, seconds = round_of(test, examples, args.hang)
            runs[test].append(seconds)
            print(
                f"{test}: round {len(runs[test])}, {examples} examples, {seconds:.1f} s: {'ok' if passed else 'FAILED'}",
                flush=True,
            )
            if not passed:
                print(report)
                return 1
            if not args.quick and time.monotonic() >= deadline:
                break
    print("\n| parser | rounds | examples | seconds |\n|---|---|---|---|")
    for test, times in runs.items():
        print(f"| {test} | {len(times)} | {len(times) * examples} | {sum(times):.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
