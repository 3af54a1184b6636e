"""DDS domain ids for the tests: each test that starts ROS processes gets a private one.

Several suites (other worktrees), benchmarks and ``make demo`` run at once on this
machine. A domain id is taken with an exclusive cross-process lock
(:mod:`pmdc_ident.process.dds_domain`, ``/tmp/pmdc_dds_domain_<id>.lock``) and held
for the test's duration, so no two of them ever share one. The pool leaves out
42 (``make demo``) and 11-20 (``make test ROS_DOMAIN_ID=...``).

- ``ros_domain``: a domain id held for one test;
- ``module_ros_domain``: one held for a module (a driver shared by its tests);
- the whole session also holds one and puts it in ``ROS_DOMAIN_ID``, so a process
  started without an explicit domain is private too.

Under pytest-xdist (``make test``) the controller also starts ``helpers/warm_kernels.py``
at once, which compiles the numba kernels into the on-disk cache while the workers
start, and each worker begins with tests that compile nothing (:data:`_FIRST`): on a
fresh clone every process that reached a kernel before another had cached it compiled
it again (~80 CPU-s of the suite's ~590 on this 2-core machine). Nothing waits for the
warm-up: a kernel it has not cached yet is compiled where it is called, as without it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from pmdc_ident.process.dds_domain import HELD_ENV, allocate_domain

_LOOPBACK_PROFILE = os.path.join(
    os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "config", "fastdds_localhost.xml"
)


def pytest_configure(config: pytest.Config) -> None:
    # DDS stays on this machine even when pytest is run directly, not through make:
    # the loopback-only Fast DDS profile (2.14 and 3 read different names) and
    # localhost discovery, unless the caller already chose.
    os.environ.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", _LOOPBACK_PROFILE)
    os.environ.setdefault("FASTDDS_DEFAULT_PROFILES_FILE", _LOOPBACK_PROFILE)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # A suite started as a background job of a non-interactive shell (`make test &`)
    # inherits SIGINT ignored, and every process it starts would ignore Ctrl-C too:
    # the tests that send SIGINT (CLI interrupts, nodes, bring-up) would then test
    # nothing. A handler here is reset to the default in each child at exec.
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if _workers(config) and not hasattr(config, "workerinput") and not config.option.collectonly:
        config._pmdc_warm_up = subprocess.Popen(  # type: ignore[attr-defined]
            [sys.executable, "-m", "helpers.warm_kernels"],
            cwd=_HERE,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )


def pytest_unconfigure(config: pytest.Config) -> None:
    proc = getattr(config, "_pmdc_warm_up", None)
    if proc is not None:
        if proc.poll() is None:  # a run shorter than the warm-up
            proc.kill()
        proc.wait()


_HERE = os.path.dirname(os.path.abspath(__file__))

#: Modules that compile no kernel (import probes, lint, C firmware, start-up): each
#: worker's share of the tests begins with some of them, while the warm-up compiles.
_FIRST = (
    "test_ros_free_core.py",
    "test_cli_startup.py",
    "test_colcon_build.py",
    "test_firmware_c.py",
    "test_layers.py",
    "test_log_levels.py",
    "test_lint.py",
    "test_launch_files.py",
)


#: The tests that take longest on the wall clock, with their seconds on a clean clone
#: (3a3b90d, 27c8f5f; idle): each worker starts its share of them right after its share
#: of :data:`_FIRST`, the longest first onto the worker with the fewest seconds so far.
#: Left to the path order, the DDS sessions of test/nodes/ come last, and the suite ended
#: with one worker idle while the other ran a 45 s session alone. An entry is a node-id
#: prefix: tests that share a module-scoped session are one entry, kept on one worker
#: (split, each worker would run the session).
_LONG = (
    ("test/nodes/test_identification_node.py::test_full_default_sequence_recovers", 45),
    ("test/commands/test_property_signals.py::test_no_signal_and_no_output_path", 19),
    ("test/nodes/test_monitor_node.py::", 18),  # the heating session and its readers
    ("test/nodes/test_plan_auto_dds.py::test_a_travel_limited_joint", 15),
    ("test/benchmark/test_mujoco_plant.py::test_quick_mujoco_benchmark_prints", 14),
    ("test/nodes/test_identification_node.py::test_crashed_recorder_aborts", 13),
    ("test/nodes/test_identification_node.py::test_a_killed_recorder_aborts", 0),  # same
    ("test/benchmark/test_benchmark_generator.py::test_quick_benchmark_command_prints", 7),
)


def _long_shares(items: list[pytest.Item], n: int) -> list[list[pytest.Item]]:
    """:data:`_LONG`'s tests dealt to ``n`` workers: each entry whole, in its order,
    onto the worker with the fewest seconds so far (an entry of 0 s goes where the one
    before it went: the same session)."""
    shares: list[list[pytest.Item]] = [[] for _ in range(n)]
    load = [0.0] * n
    k = 0
    for prefix, seconds in _LONG:  # listed longest first
        group = [it for it in items if it.nodeid.startswith(prefix)]
        if seconds > 0:
            k = min(range(n), key=load.__getitem__)
        shares[k] += group
        load[k] += seconds
    return shares


def _workers(config: pytest.Config) -> int:
    """How many xdist workers run the tests (0 without xdist), in the controller and in
    each worker (where xdist clears ``numprocesses``)."""
    workerinput = getattr(config, "workerinput", None)
    if workerinput is not None:
        return int(workerinput["workercount"])
    n = getattr(config.option, "numprocesses", None)
    return n if isinstance(n, int) else 0


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Under xdist, put a share of :data:`_FIRST`'s tests, then of :data:`_LONG`'s, at the
    start of each worker's first batch; the order within a module is kept otherwise.
    Every worker computes the same order (xdist requires it)."""
    n = _workers(config)
    if n < 2:
        return
    first = [it for it in items if it.path.name in _FIRST]
    long = _long_shares([it for it in items if it.path.name not in _FIRST], n)
    taken = {id(it) for share in long for it in share}
    if not first and not taken:
        return
    rest = [it for it in items if it.path.name not in _FIRST and id(it) not in taken]
    shares = [first[k * len(first) // n : (k + 1) * len(first) // n] + long[k] for k in range(n)]
    # xdist's first distribution (load, worksteal): each of the n workers in turn takes
    # len(pending) // (workers left) of the pending items, from the front
    order: list[pytest.Item] = []
    left = len(items)
    for k in range(n):
        size = left // (n - k)
        take = max(0, size - len(shares[k]))
        order += shares[k] + rest[:take]
        rest = rest[take:]
        left -= size
    order += rest
    items[:] = order


@pytest.fixture(scope="session", autouse=True)
def _session_ros_domain() -> Iterator[int]:
    old = os.environ.get("ROS_DOMAIN_ID")
    with allocate_domain(purpose="pytest session default") as lock:
        os.environ["ROS_DOMAIN_ID"] = str(lock.domain_id)
        try:
            yield lock.domain_id
        finally:
            if old is None:
                os.environ.pop("ROS_DOMAIN_ID", None)
            else:
                os.environ["ROS_DOMAIN_ID"] = old


def _held(purpose: str) -> Iterator[int]:
    names = ("ROS_DOMAIN_ID", HELD_ENV)
    before = {k: os.environ.get(k) for k in names}
    with allocate_domain(purpose=purpose) as lock:
        try:
            yield lock.domain_id
        finally:  # a test may have put its domain into os.environ (in-process rclpy)
            for k, v in before.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


@pytest.fixture
def ros_domain(request: pytest.FixtureRequest) -> Iterator[int]:
    """A DDS domain id no other process on this machine uses during this test."""
    yield from _held(f"pytest {request.node.nodeid}"[:120])


@pytest.fixture(scope="module")
def module_ros_domain(request: pytest.FixtureRequest) -> Iterator[int]:
    """A DDS domain id no other process on this machine uses during this module."""
    yield from _held(f"pytest {request.module.__name__}"[:120])
