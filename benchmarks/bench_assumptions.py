"""Issue 22's goals, measured: every modelling assumption checked against the data.

    .venv/bin/python benchmarks/bench_assumptions.py [--out DIR] [--skip-diagnose]
        [--generator-seeds 1,2] [--bag PATH]

Runs, on whatever ``pmdc_ident`` this interpreter imports (for a "before" column,
put an older checkout first: ``PYTHONPATH=/path/to/old/tree python THIS``):

1. the foreign-shapes corpus (``test/helpers/foreign.py``: records made by scipy's
   ``solve_ivp`` on equations written there, or by MuJoCo's ``<dcmotor>``; never by
   the package's simulator) through ``pmdc-ident identify --json --yaml``: per record
   the outcome, the **confident-wrong** parameters (the truth outside the reported 95 %
   interval by more than 3 standard errors while the parameter is not flagged), the
   YAML through ``pmdc-ident export-model --mujoco``, and every rate or value the
   advice names against what hardware offers (current sensing up to 100 kHz);
2. ``pmdc-ident diagnose`` on the joined runs with a running clock and on the same
   runs with 1 s inserted between them: the verdicts must agree, clean runs
   ``no_gap``; and whether ``identify`` and ``diagnose`` read the segments alike
   (which segments continue the one before);
3. the benchmark generator's sessions (``pmdc_ident.benchmark``; real continuations):
   how many of their segment boundaries are read as separate runs (must be 0);
4. seed 000's tables, a demo-sized session bag of the seed-000 motor (the recorder's
   format; ``--bag`` for a recorded one) and the fixtures: every warning ``check`` and
   ``identify`` print, to compare before/after.

The benchmark generator's verdicts on a reduced draw, before and after::

    pmdc-ident benchmark --runs-per-effect 1 --clean 2 --oov 1 --pairs 1 --seed 1 \
        --jobs 2 --json after.json            (and the old tree's, before.json)
    python benchmarks/bench_assumptions.py --compare-draws before.json after.json
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "test"))

from pmdc_ident._blas import limit_blas_threads  # noqa: E402

limit_blas_threads()

HARDWARE_MAX_HZ = 100e3  # the fastest current sensing a motor drive offers
FLAG_WORDS = ("NOT IDENTIFIABLE", "weakly", "assumed", "fixed")


def cli(args: list[str]) -> tuple[int, str, str]:
    """``pmdc-ident ARGS`` in this process: exit status, stdout, stderr."""
    from pmdc_ident.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(args)
        except SystemExit as exc:  # argparse
            code = int(exc.code or 0)
    return int(code or 0), out.getvalue(), err.getvalue()


_RATE = re.compile(r"(\d[\d.e+]*)\s*(k?Hz)")


def advice_beyond_hardware(text: str) -> list[str]:
    bad = []
    for m in _RATE.finditer(text):
        try:
            hz = float(m.group(1)) * (1e3 if m.group(2) == "kHz" else 1.0)
        except ValueError:
            continue
        if hz > HARDWARE_MAX_HZ:
            bad.append(m.group(0))
    return bad


def identify_record(rec: Any, folder: Path) -> dict[str, Any]:
    from helpers.foreign import confident_wrong, flagged

    csv = rec.write(folder / f"{rec.name}.csv")
    js, ym = folder / f"{rec.name}.json", folder / f"{rec.name}.yaml"
    argv = ["identify", str(csv), "--json", str(js), "--yaml", str(ym), "--quiet"]
    code, out, err = cli([*argv, *rec.options])
    row: dict[str, Any] = {"record": rec.name, "made_by": rec.made_by, "exit": code}
    if code != 0:
        last = err.strip().splitlines()[-1][:150] if err.strip() else ""
        row["outcome"] = f"exit {code}: {last}"
        row["wrong"] = []
        row["yaml"] = "-"
        row["advice"] = []
        return row
    body = json.loads(js.read_text())
    params = body["parameters"]
    row["wrong"] = confident_wrong(params, rec.truth)
    flags = [n for n in ("R", "L", "Ke", "Kt", "J", "B") if n in params and flagged(params[n])]
    errs = []
    for n in ("R", "L", "Ke", "J", "B"):
        if n in params and n in rec.truth and not flagged(params[n]):
            errs.append(f"{n} {100 * (params[n]['value'] / rec.truth[n] - 1):+.1f}%")
    row["outcome"] = (", ".join(errs) or "-") + (f"; flagged {', '.join(flags)}" if flags else "")
    xml = folder / f"{rec.name}.xml"
    c2, _o2, e2 = cli(["export-model", str(ym), "--mujoco", str(xml)])
    row["yaml"] = "ok" if c2 == 0 else ("refused: " + (e2.strip().splitlines() or ["?"])[-1][:90])
    row["advice"] = advice_beyond_hardware(out + err)
    row["segments"] = segments_of(body)
    return row


def segments_of(body: dict[str, Any]) -> list[tuple[str, bool]] | None:
    """(label, continues the one before) per segment as a command's JSON tells it."""
    reading = body.get("assumptions_checked", {}).get("segments")
    if reading is not None:
        return [(s["label"], bool(s["continues"])) for s in reading]
    return None


def diagnose_record(rec: Any, folder: Path) -> dict[str, Any]:
    csv = rec.write(folder / f"{rec.name}.csv")
    js = folder / f"{rec.name}.diag.json"
    code, out, err = cli(["diagnose", str(csv), "--json", str(js), "--quiet"])
    if code != 0:
        return {"verdict": f"exit {code}", "segments": None, "gap": ""}
    body = json.loads(js.read_text())
    v = body["verdict"]
    gap = f"{body['holdout']['gap_before']:.3g} -> {body['holdout']['gap_after']:.3g}"
    status = v["status"] + (f" ({'+'.join(v['effects'])})" if v["effects"] else "")
    return {"verdict": status, "segments": segments_of(body), "gap": gap}


def legacy_reading(csv: Path, command: str) -> list[tuple[str, bool]]:
    """How the code before issue 22 read the segments (it did not say so in its JSON):
    diagnose predicted a held-out segment as the continuation of a contiguous one
    (its lead-in), identify estimated every segment's state afresh."""
    from pmdc_ident.dataio import load_data

    run = load_data(csv)
    out = []
    for s in run.segments:
        linked = s.history_voltage is not None and s.history_voltage.size > 0
        out.append((s.label, linked if command == "diagnose" else False))
    return out


def generator_boundaries(seeds: list[int]) -> tuple[int, int]:
    """Segment boundaries of the benchmark generator's sessions, and how many of them
    are read as separate runs (each draw: 1 run per effect, 2 clean, 1 pair)."""
    from pmdc_ident.benchmark.cases import build_cases, record
    from pmdc_ident.benchmark.runner import write_recording
    from pmdc_ident.dataio import load_data

    total = separate = 0
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            for case in build_cases(1, 2, 1, 1, seed):
                try:
                    rec, _ = record(case)
                except (ValueError, ArithmeticError):
                    continue
                path = write_recording(rec, Path(tmp) / f"c{case.seed}.csv")
                segs = load_data(path).segments
                for s in segs[1:]:
                    total += 1
                    linked = s.history_voltage is not None and s.history_voltage.size > 0
                    separate += not linked
    return total, separate


def warnings_on(paths: list[str], opts: list[str] = ()) -> dict[str, list[str]]:
    out = {}
    for cmd in ("check", "identify"):
        code, o, e = cli([cmd, *paths, *opts, *(["--quiet"] if cmd == "identify" else [])])
        lines = [ln.strip() for ln in (o + e).splitlines()]
        keep = [ln for ln in lines if ln.startswith(("warning:", "error:", "- "))]
        if cmd == "identify":
            # the result's warnings block
            block, on = [], False
            for ln in (o + e).splitlines():
                if ln.startswith("warnings:"):
                    on = True
                    continue
                if on and not ln.startswith("  - "):
                    on = False
                if on:
                    block.append(ln.strip())
            keep = [ln for ln in lines if ln.startswith("warning:")] + block
        out[cmd] = [f"exit {code}"] + keep
    return out


def compare_draws(before: Path, after: Path) -> int:
    """Verdicts of two ``pmdc-ident benchmark --json`` files of one draw, run by run."""
    a = {r["name"]: r for r in json.loads(before.read_text())}
    b = {r["name"]: r for r in json.loads(after.read_text())}
    changed = 0
    for name in sorted(a.keys() & b.keys()):
        va = (a[name]["status"], a[name]["effects"])
        vb = (b[name]["status"], b[name]["effects"])
        if va != vb:
            changed += 1
            print(f"  {name}: {va[0]} {'+'.join(va[1])} -> {vb[0]} {'+'.join(vb[1])}")
    print(
        f"benchmark draw: {len(a.keys() & b.keys())} runs in both, {changed} verdicts changed"
        + (f"; only in one: {sorted(a.keys() ^ b.keys())}" if a.keys() ^ b.keys() else "")
    )
    return changed


def demo_bag(folder: Path) -> Path:
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.bagio import write_bag

    spec = load_motor("seed000_ebike")
    plan = plan_for_motor(spec, 1e-3)
    bag = folder / "demo_session"
    write_bag(synthesize_run(spec.model, plan, spec.sensors, seed=7), bag)
    return bag


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the records and JSON here")
    ap.add_argument("--skip-diagnose", action="store_true")
    ap.add_argument("--generator-seeds", default="1,2,3")
    ap.add_argument("--bag", default=None, help="a recorded session bag to check as well")
    ap.add_argument(
        "--compare-draws",
        nargs=2,
        type=Path,
        metavar=("BEFORE.json", "AFTER.json"),
        help="only compare the verdicts of two `pmdc-ident benchmark --json` files of one draw",
    )
    args = ap.parse_args(argv)
    if args.compare_draws:
        compare_draws(*args.compare_draws)
        return 0
    from helpers.foreign import concatenated, corpus

    import pmdc_ident

    print(f"pmdc_ident from {Path(pmdc_ident.__file__).parent}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        rows = [identify_record(rec, folder) for rec in corpus()]
        print(f"\n## foreign corpus through identify ({time.perf_counter() - t0:.0f} s)\n")
        head = ["record", "made by", "outcome", "confident-wrong", "YAML -> export-model"]
        print("| " + " | ".join([*head, "advice beyond hardware"]) + " |")
        print("| --- | --- | --- | --- | --- | --- |")
        for r in rows:
            wrong = "; ".join(r["wrong"]) or "0"
            advice = ", ".join(r["advice"]) or "none"
            cells = [r["record"], r["made_by"], r["outcome"], wrong, r["yaml"], advice]
            print("| " + " | ".join(cells) + " |")
        n_wrong = sum(len(r["wrong"]) for r in rows)
        n_yaml = sum(r["yaml"] not in ("ok", "-") for r in rows)
        n_adv = sum(len(r["advice"]) for r in rows)
        print(
            f"\nconfident-wrong parameters: {n_wrong}; YAMLs refused: {n_yaml}; "
            f"advice beyond hardware: {n_adv}"
        )

        if not args.skip_diagnose:
            print("\n## joined runs: diagnose with a running clock vs with 1 s gaps\n")
            print(
                "| record | verdict | held-out gap | identify/diagnose read the segments alike |"
            )
            print("| --- | --- | --- | --- |")
            differ = 0
            idents = {r["record"]: r for r in rows}
            for rec in (concatenated(), concatenated(gap_s=1.0)):
                d = diagnose_record(rec, folder)
                ident = idents[rec.name].get("segments")
                diag = d["segments"]
                csv = folder / f"{rec.name}.csv"
                ident = ident if ident is not None else legacy_reading(csv, "identify")
                diag = diag if diag is not None else legacy_reading(csv, "diagnose")
                same = ident == diag
                differ += not same
                print(f"| {rec.name} | {d['verdict']} | {d['gap']} | {'yes' if same else 'no'} |")
            print(f"\nruns where identify and diagnose read the segments differently: {differ}")

        seeds = [int(s) for s in args.generator_seeds.split(",") if s]
        total, sep = generator_boundaries(seeds)
        print(
            f"\n## benchmark generator sessions (seeds {seeds}): {sep} of {total} segment "
            "boundaries read as separate runs (real continuations: must be 0)"
        )

        print("\n## warnings on the seed-000 tables, a demo-sized bag and the fixtures\n")
        fixtures = [
            str(ROOT / "test/fixtures/seed000_table4.csv"),
            str(ROOT / "test/fixtures/seed000_retardation.csv"),
        ]
        cases = {"seed-000 tables (--fix R=1.375)": (fixtures, ["--fix", "R=1.375"])}
        cases["demo-sized session bag"] = ([str(demo_bag(folder))], [])
        if args.bag:
            cases[f"bag {args.bag}"] = ([args.bag], [])
        for name, (paths, opts) in cases.items():
            found = warnings_on(paths, opts)
            for cmd, lines in found.items():
                print(f"{name}: {cmd}: {lines[0]}")
                for ln in lines[1:]:
                    print(f"    {ln}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
