"""What the session controller exchanges with its node: the node's side
(:class:`ControllerPorts`), the identification job it hands over and its outcome."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from pmdc_ident.core.enums import LogLevel
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.samples import DriverSamples

__all__ = ["ControllerPorts", "ExportRequest", "IdentificationJob", "IdentificationOutcome"]


@dataclass(frozen=True)
class ExportRequest:
    """The identified motor in other tools' formats, written beside the session's results
    (:func:`pmdc_ident.exports.write_exports`: MJCF, URDF, ros2_control, gains)."""

    reduction: float = 1.0  # motor turns per joint turn
    speed_bandwidth_hz: float = 0.0  # 0: a tenth of the current loop's crossover
    phase_margin_deg: float = 60.0
    sample_rate_hz: float = 0.0  # the gains' rate; 0 until the controller sets the session's
    joint: str = ""  # the joint's name; '' until the controller sets the driver's joint_name


@dataclass(frozen=True)
class IdentificationJob:
    """A finished session's samples, to be identified off the node's I/O callbacks."""

    samples: DriverSamples
    session: str
    source: str  # the bag's path, or 'session <name>' without a recorder
    output_dir: Path
    fixed: Mapping[str, float]
    exports: ExportRequest | None = None  # None: no exports
    extra: Mapping[str, object] | None = None  # entries added to the result (plan: auto)


@dataclass(frozen=True)
class IdentificationOutcome:
    """What the identification job returns: the result documents, or why it failed."""

    json_text: str = ""
    table: str = ""
    n_samples: int = 0
    output_dir: str = ""
    error: str = ""
    exit_code: int = 0  # an ExitCode: USER_ERROR the data were refused (one line), FAILED a bug
    notes: tuple[tuple[LogLevel, str], ...] = ()  # (level, text) lines for the node's log


class ControllerPorts(Protocol):
    """The node's side: publications, service calls and logs."""

    def send_voltage(self, voltage_v: float) -> None: ...

    def open_armature(self) -> bool:
        """Call the driver's open_armature service; False when it is not available."""

    def publish_marker(self, text: str) -> None: ...

    def publish_progress(self, text: str) -> None: ...

    def publish_status(self, text: str) -> None: ...

    def publish_result(self, text: str) -> None: ...

    def request_driver_parameters(self, names: tuple[str, ...]) -> bool:
        """Ask the driver node for ``names``; False when it is not reachable yet. The
        answer comes back through :meth:`SessionController.on_driver_parameters`."""

    def prepare_identification(self, nominal: MotorSpec | None) -> None:
        """A session started: get the identification ready (imports, compiled kernels)
        while it runs, so that :meth:`start_identification` costs only the fit. Also
        called on every start-up tick of a ``plan: auto`` session (its designs need the
        worker from the pre-test's end on): a worker already there is kept."""

    def start_design(self, job: object) -> None:
        """Run a ``plan: auto`` re-fit and design job (:class:`~.sequential.DesignJob`) off
        the I/O callbacks; its outcome comes back through
        :meth:`SessionController.on_design`."""

    def start_identification(self, job: IdentificationJob) -> None:
        """Run the job off the I/O callbacks; its outcome comes back through
        :meth:`SessionController.on_identified`."""

    def log(self, level: LogLevel, text: str) -> None:
        """A line for the node's logger at ``level``."""
