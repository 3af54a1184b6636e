"""Diagnose a chosen subset of one benchmark draw, its cases identical to the full draw's.

``pmdc-ident benchmark --effects`` draws a different set of cases (the draw's random
stream runs over the effects it is given); this keeps the full draw of ``--counts``
(runs per effect, effect-free, per out-of-vocabulary name, pairs) and runs only the
cases of ``--kinds`` whose names start with one of ``--names``. Example, the blind
seed 2 subset's effect-free MuJoCo runs::

    nice .venv/bin/python benchmarks/bench_subset.py --plant mujoco --seed 2 \
        --counts 8,10,3,4 --kinds clean
"""

from __future__ import annotations

import argparse
import json
import sys

from pmdc_ident.benchmark.cases import build_cases
from pmdc_ident.benchmark.runner import Outcome, run_cases


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", choices=("generator", "mujoco"), default="generator")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--counts", default="24,30,4,12", help="effect,clean,oov,pairs")
    ap.add_argument("--kinds", default="clean", help="effect,clean,oov,compound")
    ap.add_argument("--names", default="", help="name prefixes (all when empty)")
    ap.add_argument("--json", default="")
    a = ap.parse_args()
    counts = [int(x) for x in a.counts.split(",")]
    if a.plant == "mujoco":
        from pmdc_ident.benchmark.mujoco_cases import build_mj_cases as build
    else:
        build = build_cases
    prefixes = tuple(a.names.split(",")) if a.names else ("",)
    cases = [
        c
        for c in build(*counts, a.seed)
        if c.kind in a.kinds.split(",") and c.name.startswith(prefixes)
    ]
    print(f"{len(cases)} cases", file=sys.stderr, flush=True)

    def progress(k: int, n: int, o: Outcome) -> None:
        print(
            f"[{k}/{n}] {o.case.name} {o.case.motor} {o.case.rate_hz:g} Hz "
            f"visibility {o.case.visibility:.3g} -> {o.status} {'+'.join(o.effects)} "
            f"| {o.message[:110]}",
            flush=True,
        )

    outs = run_cases(cases, jobs=1, progress=progress)
    if a.json:
        rows = [
            {"name": o.case.name, "kind": o.case.kind, "visibility": o.case.visibility,
             "status": o.status, "effects": list(o.effects)}
            for o in outs
        ]  # fmt: skip
        from pmdc_ident.core.safe_write import write_text

        write_text(a.json, json.dumps(rows))  # atomically: never half a file under its name
    return 0


if __name__ == "__main__":
    sys.exit(main())
