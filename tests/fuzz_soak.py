"""The importer fuzzers for a set time (``make fuzz-soak``, default one hour): mutated and random
OBJ, PLY, glTF, GLB and Mitsuba XML files, each loaded by a worker process that must return a
scene or the one-line `InputError` (tests/test_fuzz_importers.py's rule).

A worker that dies (a crash in a native library) or answers nothing for HANG_SECONDS + GRACE
(a hang that the worker's own alarm cannot interrupt) is counted, its example saved under
``--out``, and a new worker goes on. Example i of seed s is the same file on every run, so a
saved failure can be replayed with ``--replay s:i``. Prints a table and, last, one JSON line.
"""

from __future__ import annotations

import argparse
import itertools
import json
import multiprocessing
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from test_fuzz_importers import FORMATS, HANG_SECONDS, SEEDS, load_or_one_line_error, mutate

GRACE = 10
KINDS = ("mutated", "random")


def example(seed: int, index: int) -> tuple[str, str, bytes]:
    """(format, kind, file bytes) of example ``index``: four in five mutate a valid file with 1 to
    8 edits, one in five is up to 4 KiB of random bytes."""
    rng = np.random.default_rng([seed, index])
    ext = FORMATS[rng.integers(len(FORMATS))]
    if rng.random() < 0.2:
        return ext, "random", rng.bytes(int(rng.integers(0, 4097)))
    kinds = ("insert", "delete", "replace", "duplicate")
    ops = [
        (kinds[rng.integers(4)], rng.random(), rng.bytes(int(rng.integers(1, 13)))) for _ in range(rng.integers(1, 9))
    ]
    return ext, "mutated", mutate(SEEDS[ext], ops)


def worker(seed: int, connection, folder: str) -> None:
    os.environ["EVALKIT_CACHE"] = "off"  # every example imported, none kept
    while True:
        index = connection.recv()
        ext, _, data = example(seed, index)
        path = Path(folder) / f"example.{ext}"
        path.write_bytes(data)
        try:
            outcome = "scene" if load_or_one_line_error(path) is not None else "one-line error"
        except BaseException as e:  # noqa: BLE001 - anything but a scene or an InputError is the finding
            outcome = f"failure: {type(e).__name__}: {' '.join(str(e).split())[:300]}"
        connection.send(outcome)


def soak(seconds: float, seed: int, out: Path, replay: int | None = None) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    tally = {(ext, kind): {"tried": 0, "scenes": 0, "errors": 0} for ext in FORMATS for kind in KINDS}
    failures, start = [], time.monotonic()
    context = multiprocessing.get_context("spawn")  # a fresh interpreter, no GL or Mitsuba state
    with tempfile.TemporaryDirectory() as folder:
        process = None
        for index in [replay] if replay is not None else itertools.count():
            if replay is None and time.monotonic() - start >= seconds:
                break
            if process is None:
                mine, theirs = context.Pipe()
                process = context.Process(target=worker, args=(seed, theirs, folder), daemon=True)
                process.start()
            ext, kind, data = example(seed, index)
            mine.send(index)
            outcome = mine.recv() if mine.poll(HANG_SECONDS + GRACE) else None
            if outcome is None or not process.is_alive():
                outcome = "hang" if process.is_alive() else f"crash (exit {process.exitcode})"
                process.kill()
                process.join()
                process = None
            row = tally[(ext, kind)]
            row["tried"] += 1
            row["scenes"] += outcome == "scene"
            row["errors"] += outcome == "one-line error"
            if outcome not in ("scene", "one-line error"):
                saved = out / f"seed{seed}-{index}.{ext}"
                saved.write_bytes(data)
                failures.append({"example": f"{seed}:{index}", "file": str(saved), "outcome": outcome})
                print(f"FAIL {seed}:{index} {ext} {kind}: {outcome} (saved {saved})", flush=True)
        if process is not None:
            process.kill()
    return {"seconds": round(time.monotonic() - start, 1), "seed": seed, "tally": tally, "failures": failures}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=3600.0)
    parser.add_argument("--seed", type=int, default=int(time.time()))
    parser.add_argument(
        "--out", type=Path, default=Path("out/fuzz-soak"), help="failing examples (default out/fuzz-soak)"
    )
    parser.add_argument("--replay", metavar="SEED:INDEX", help="load one example again")
    args = parser.parse_args(argv)
    replay = None
    if args.replay:
        args.seed, replay = (int(x) for x in args.replay.split(":"))
    result = soak(args.seconds, args.seed, args.out, replay)
    print(f"{'format':8} {'kind':8} {'tried':>8} {'scenes':>8} {'errors':>8}")
    for (ext, kind), row in result["tally"].items():
        print(f"{ext:8} {kind:8} {row['tried']:8d} {row['scenes']:8d} {row['errors']:8d}")
    tried = sum(row["tried"] for row in result["tally"].values())
    hangs = sum(f["outcome"] == "hang" for f in result["failures"])
    crashes = sum(f["outcome"].startswith("crash") for f in result["failures"])
    print(f"{tried} examples in {result['seconds']} s (seed {args.seed}): {len(result['failures'])} failures")
    summary = {
        "examples": tried,
        "failures": len(result["failures"]),
        "hangs": hangs,
        "crashes": crashes,
        "seconds": result["seconds"],
        "seed": args.seed,
        "python": sys.version.split()[0],
        "first_failures": result["failures"][:20],
    }
    print(json.dumps(summary))
    return 1 if result["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())
