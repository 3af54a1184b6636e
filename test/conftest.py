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
"""

from __future__ import annotations

import os
import signal
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
