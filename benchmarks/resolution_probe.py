"""The resolution probe (`evalkit scene info`'s advice of R) by stage: the exact tracer (Embree's
scene and the coincident triangles it layers apart) and the advice (the lookups at each R tried,
with the triangles' neighbours the walks cross, found once per scene), against the 30 s a probe of
a 2 M-triangle scene may take.

    python benchmarks/resolution_probe.py [--scenes atrium-dense atrium] [--repeats 1] [--record JSON]

Each repeat loads the scene afresh, so nothing found by one is reused by the next. Medians over
the repeats, wall time on this machine. Prints a table; the last line is one JSON object with
every figure.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

from evalkit.core.scene import load_scene
from evalkit.metrics.bundles import resolution_advice
from evalkit.records import write_record
from references.embree import ExactTracer

TARGET_S = 30.0  # a probe of a 2 M-triangle scene, on 2 cores


def probe(name: str) -> dict:
    """One probe of scene ``name``: seconds per stage, and what it advised."""
    start = time.perf_counter()
    scene = load_scene(name)
    loaded = time.perf_counter()
    tracer = ExactTracer(scene)
    traced = time.perf_counter()
    advice = resolution_advice(scene, tracer)
    done = time.perf_counter()
    return {
        "triangles": int(len(tracer.arrays.faces)),
        "coincident_pairs": int(len(tracer.coincident_pairs)),
        "load_s": loaded - start,
        "tracer_s": traced - loaded,
        "advice_s": done - traced,
        "probe_s": done - loaded,
        "recommended": advice["recommended"],
        "wrong_lookups_per_path": advice["wrong_lookups_per_path"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="+", default=["atrium-dense", "atrium"])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--record", metavar="JSON", help="also save the report with its command and versions there")
    args = parser.parse_args()
    rows = []
    print(f"{'scene':14}{'triangles':>11}{'tracer s':>10}{'advice s':>10}{'probe s':>9}  advice")
    for name in args.scenes:
        runs = [probe(name) for _ in range(args.repeats)]
        row = {**runs[-1], **{k: statistics.median(r[k] for r in runs) for k in ("tracer_s", "advice_s", "probe_s")}}
        row["scene"] = name
        rows.append(row)
        print(
            f"{name:14}{row['triangles']:>11,}{row['tracer_s']:>10.1f}{row['advice_s']:>10.1f}{row['probe_s']:>9.1f}"
            f"  R >= {row['recommended']}"
        )
    largest = max(rows, key=lambda r: r["triangles"])
    print(f"target      a probe of {largest['scene']} ({largest['triangles']:,} triangles) within {TARGET_S:g} s")
    report = {"benchmark": "resolution_probe", "repeats": args.repeats, "target_s": TARGET_S, "rows": rows}
    if args.record:
        write_record(args.record, report)
    print(json.dumps(report))


if __name__ == "__main__":
    main()
