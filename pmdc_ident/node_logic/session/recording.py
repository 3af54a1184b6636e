"""What the identification node records during a session: the driver's samples per
topic as growing numpy columns (stamp in ns on the driver's clock, values in SI units)
and the receive latency of every encoder sample."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.markers import Marker
from pmdc_ident.core.samples import DriverSamples

__all__ = ["Columns", "Recording"]


class Columns:
    """Preallocated, growing numpy columns (stamp ns + values) for one topic."""

    def __init__(self, n_values: int, capacity: int = 65536) -> None:
        self.ns = np.zeros(capacity, dtype=np.int64)
        self.v = np.zeros((capacity, n_values))
        self.n = 0

    def clear(self) -> None:
        self.n = 0

    def append(self, ns: int, *values: float) -> None:
        if self.n >= self.ns.size:
            self.ns = np.concatenate([self.ns, np.zeros_like(self.ns)])
            self.v = np.concatenate([self.v, np.zeros_like(self.v)])
        self.ns[self.n] = ns
        self.v[self.n] = values
        self.n += 1

    def last_ns(self) -> int:
        return int(self.ns[self.n - 1]) if self.n else -1

    def stamps(self) -> NDArray[np.int64]:
        return self.ns[: self.n].copy()

    def values(self, k: int) -> NDArray[np.float64]:
        return self.v[: self.n, k].copy()

    def values_since(self, ns: int, k: int) -> NDArray[np.float64]:
        """Column ``k`` of the samples stamped at or after ``ns``."""
        first = int(np.searchsorted(self.ns[: self.n], ns, side="left"))
        return self.v[first : self.n, k].copy()


class Recording:
    """The three driver topics of one session and the encoder samples' latency."""

    def __init__(self) -> None:
        self.current = Columns(1)
        self.encoder = Columns(2)
        self.voltage = Columns(2)
        self.latency = Columns(0)  # receive time - driver stamp, ns

    def clear(self) -> None:
        for col in (self.current, self.encoder, self.voltage, self.latency):
            col.clear()

    def complete_until(self, end_ns: int) -> bool:
        """Every topic holds a sample stamped at or after ``end_ns``."""
        have = min(self.current.last_ns(), self.voltage.last_ns(), self.encoder.last_ns())
        return have >= end_ns

    def max_latency_s(self, since_ns: int) -> float:
        """The latest an encoder sample stamped at or after ``since_ns`` reached the node
        (s; 0 with none): how late a command sent on it left, at the least."""
        n = self.encoder.n
        first = int(np.searchsorted(self.encoder.ns[:n], since_ns, side="left"))
        lag = self.latency.ns[first:n]
        return float(lag.max()) * 1e-9 if lag.size else 0.0

    def latency_summary(self) -> str:
        lag_ms = self.latency.ns[: self.latency.n] * 1e-6
        if lag_ms.size == 0:
            return "no samples"
        return (
            f"median {np.median(lag_ms):.1f} ms, 99th percentile "
            f"{np.percentile(lag_ms, 99):.1f} ms, max {lag_ms.max():.1f} ms at sample "
            f"{int(np.argmax(lag_ms))}"
        )

    def samples(self, markers: tuple[Marker, ...]) -> DriverSamples:
        terminal = self.voltage.values(1)
        return DriverSamples(
            current_ns=self.current.stamps(),
            current_a=self.current.values(0),
            encoder_ns=self.encoder.stamps(),
            position_rad=self.encoder.values(0),
            speed_rad_s=self.encoder.values(1),
            voltage_ns=self.voltage.stamps(),
            voltage_v=self.voltage.values(0),
            terminal_v=terminal if np.isfinite(terminal).any() else None,
            markers=markers,
        )
