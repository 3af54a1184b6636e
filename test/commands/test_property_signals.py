"""Property test over signals and output paths (issue 28, item 6): for any command, any
output path - a new file, an existing result, the input itself, its sidecar name, a
place inside the input bag, a link to the input - and any sequence of SIGINT, SIGTERM
and SIGHUP at any moment, real processes:

* every input the command reads (the CSV and its sidecar, or the bag's files) and any
  recording's sidecar is byte-identical afterwards;
* no partial file is left under a final name: each file in the output folder is the
  one that was there before, untouched, or a complete one (JSON and YAML parse, a CSV
  reads back whole, a bag reads back with its metadata, a PNG ends with its IEND);
* no temporary file is left behind, no traceback is printed, and the exit status is
  0, 2, or 128 + the first signal's number.

The default profile is a dozen examples (derandomized: the same on every machine);
``PMDC_PROPERTY_EXAMPLES=200`` hunts longer.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, example, given, seed, settings
from hypothesis import strategies as st

from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import write_bag
from pmdc_ident.dataio.csvio import write_csv

EXAMPLES = int(os.environ.get("PMDC_PROPERTY_EXAMPLES", "0")) or 12
EXE = str(Path(sys.executable).with_name("pmdc-ident"))  # the launcher users run
PREVIOUS = b"the previous, complete result\n"
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A short session as CSV (with a sidecar) and as a bag."""
    d = tmp_path_factory.mktemp("inputs")
    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(
        staircase_levels=2, staircase_hold_tau=3.0, step_hold_tau=3.0, sweep_duration_tau=8.0
    )
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=5)
    write_csv(run, d / "run.csv")
    (d / "run.csv.yaml").write_text("current_unit: A\n")
    write_bag(run, d / "bag")
    return d


# (command words, output option, suffix of a file output or None for a folder output)
COMMANDS = [
    (["export", "{csv}"], "--csv", ".csv"),
    (["export", "{csv}"], "--bag", None),
    (["export", "{bag}"], "--csv", ".csv"),
    (["identify", "{csv}", "--quiet", "--no-holdout", "--model", "linear"], "--json", ".json"),
    (["identify", "{bag}", "--quiet", "--no-holdout", "--model", "linear"], "--yaml", ".yaml"),
    (
        ["identify", "{csv}", "--quiet", "--no-holdout", "--model", "linear", "--bootstrap", "0"],
        "--report",
        None,
    ),
    (["check", "{csv}"], "--json", ".json"),
    (["plan", "{csv}"], "--csv", ".csv"),  # a plan designed from a recorded pre-test
]
TARGETS = ("new", "existing", "the input", "its sidecar name", "inside the bag", "a link")


def _digest(paths: list[Path]) -> dict[str, str]:
    out = {}
    for p in paths:
        files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def _complete(path: Path) -> bool:
    """A whole file of its kind."""
    from pmdc_ident.dataio.bagio import read_bag
    from pmdc_ident.dataio.csvio import read_csv

    if path.is_dir():
        if any(path.glob("*.mcap")):  # a bag: complete with its metadata, readable
            if not (path / "metadata.yaml").is_file():
                return False
            read_bag(path)
        return True  # a report folder: its files are checked one by one
    data = path.read_bytes()
    if data == PREVIOUS:
        return True
    suffix = path.suffix.lower()
    if suffix == ".json":
        json.loads(data)
    elif suffix in (".yaml", ".yml"):
        assert yaml.safe_load(data) is not None
    elif suffix == ".csv" and data.startswith(b"# pmdc-ident plan"):  # a planned voltage
        from pmdc_ident.core.design import plan_from_csv_text

        assert plan_from_csv_text(data.decode()).duration_s > 0
    elif suffix == ".csv":
        read_csv(path)
    elif suffix == ".png":
        return data.endswith(b"IEND\xaeB`\x82")
    elif suffix in (".mcap", ".html"):
        return len(data) > 0
    return True


def _target(kind: str, d: Path, out: Path, inputs: Path, suffix: str | None) -> str:
    name = f"result{suffix or ''}"
    if kind == "new":
        return str(out / name)
    if kind == "existing":
        p = out / name
        if suffix is not None:
            p.write_bytes(PREVIOUS)
        return str(p)
    if kind == "the input":
        return str(inputs / "run.csv")
    if kind == "its sidecar name":
        return str(inputs / "run.csv.yaml")
    if kind == "inside the bag":
        return str(inputs / "bag" / name)
    link = out / f"link{suffix or ''}"
    link.symlink_to(inputs / "run.csv")
    return str(link)


#: The default run's examples: those the derandomized run drew up to 3a3b90d. Hypothesis
#: seeds a derandomized run with a digest of the test function's source, so any edit of
#: it drew another dozen, with other targets and commands (it cost 4 s where it had cost
#: 16 by chance); pinned, an edit keeps them. A hunt (PMDC_PROPERTY_EXAMPLES) draws at
#: random.
PINNED_SEED = int(
    "1105538803588641114258952785462090401152903090955299294867322388765536318756217834"
    "4720180728144974961765989433306960"
)
_pinned = seed(PINNED_SEED) if "PMDC_PROPERTY_EXAMPLES" not in os.environ else (lambda f: f)


#: An output path that names what the command reads, once each with no signal, beside
#: the drawn dozen, which need not hold one whose command would run to its end: a plan
#: designed from run.csv written as run.csv (an export's round trip would write the same
#: bytes, and identify's JSON is refused by its suffix first), and an export written as
#: the CSV's sidecar name. Refused before anything runs; with the refusal gone
#: (``core.safe_write.conflict`` answering None) the input's digest fails.
EVERY_INPUT_TARGET = ((7, "the input"), (0, "its sidecar name"))


def _every_input_target(f):
    for command, target in EVERY_INPUT_TARGET:
        f = example(command=command, target=target, signals=[])(f)
    return f


@_pinned
@_every_input_target
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    derandomize="PMDC_PROPERTY_EXAMPLES" not in os.environ,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    command=st.sampled_from(range(len(COMMANDS))),
    target=st.sampled_from(TARGETS),
    signals=st.lists(
        st.tuples(st.sampled_from(SIGNALS), st.floats(0.0, 2.5)), min_size=0, max_size=3
    ),
)
def test_no_signal_and_no_output_path_harms_an_input_or_leaves_a_partial_file(
    inputs, tmp_path_factory, command, target, signals
):
    d = tmp_path_factory.mktemp("case")
    out = d / "out"
    out.mkdir()
    words, option, suffix = COMMANDS[command]
    argv = [w.format(csv=inputs / "run.csv", bag=inputs / "bag") for w in words]
    argv += [option, _target(target, d, out, inputs, suffix)]
    # what the command reads (its DATA and that DATA's sidecar), and the sidecar name of
    # any recording (never an output, whoever reads it)
    data = inputs / ("bag" if "{bag}" in words else "run.csv")
    watched = [data, inputs / "run.csv.yaml"]
    before_inputs = _digest(watched)
    before_out = {
        p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and not p.is_symlink()
    }
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("PMDC_IDENT_DEBUG", None)
    proc = subprocess.Popen(
        [EXE, *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=d,
    )
    t0 = time.monotonic()
    sent: list[int] = []
    sent_at: list[float] = []
    for sig, at in sorted(signals, key=lambda s: s[1]):
        # until the signal's time, or the command's end if it comes first (a sleep to
        # that time made a command done in 0.4 s wait for a signal drawn at 1.5 s)
        left = at - (time.monotonic() - t0)
        if left > 0:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=left)
        if proc.poll() is not None:
            break
        proc.send_signal(sig)
        sent.append(int(sig))
        sent_at.append(time.monotonic())
    _, err = proc.communicate(timeout=300)
    assert "Traceback" not in err and "Fatal Python error" not in err, err
    # 128 + a signal sent (said in one line), or killed by one before the command's
    # handlers exist (the interpreter still starting: nothing written yet). Python runs a
    # handler only between bytecodes, and pending handlers in signal-number order, not
    # arrival order: a signal sent while the main thread is inside one long C call (a
    # compiled kernel, an import) is pending with every later one, and any of them may be
    # acted on first (SIGTERM then SIGINT at once ended 130 at load 25; SIGTERM, then
    # SIGINT 0.37 s later, ended 130 in a clean-clone CI beside three benchmarks).
    allowed = {0, 2} | {128 + s for s in sent} | {-s for s in sent}
    assert proc.returncode in allowed, (proc.returncode, sent, err)
    assert _digest(watched) == before_inputs, (argv, err)
    for p in out.rglob("*"):
        assert ".partial" not in p.name, (p, err)
        if p.is_symlink() or (p.is_dir() and p.name != "result"):
            continue
        if p.is_file() and p.name in before_out:
            # the previous result, untouched, or (the command done) a whole new one
            same = p.read_bytes() == before_out[p.name]
            assert same or (proc.returncode == 0 and _complete(p)), (p, err)
        elif p.is_file() or p.name == "result":
            assert _complete(p), (p, err)
    assert not [p for p in inputs.rglob("*") if ".partial" in p.name]
