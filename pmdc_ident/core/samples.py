"""The driver's samples per topic: the one type both the bag reader and the session use.

The identification node collects them as a session runs
(:meth:`pmdc_ident.node_logic.session.recording.Recording.samples`); the bag reader reads
them from a recorded session (:func:`pmdc_ident.dataio.bagio.read_driver_arrays`);
:func:`pmdc_ident.dataio.bagio.assemble_run` joins either into a
:class:`~pmdc_ident.core.data.Run` the same way, so offline and online
identification see the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pmdc_ident.core.markers import Marker

__all__ = ["DriverSamples"]


@dataclass(frozen=True)
class DriverSamples:
    """Driver samples per topic: stamps in ns (driver clock) and values (SI units).

    ``position_rad`` / ``speed_rad_s`` are None when the encoder never gave them,
    ``terminal_v`` when the driver never measured the terminal voltage. ``notes``:
    what reading left out (a truncated file), one line each.
    """

    current_ns: NDArray[np.int64]
    current_a: NDArray[np.float64]
    encoder_ns: NDArray[np.int64]
    position_rad: NDArray[np.float64] | None
    speed_rad_s: NDArray[np.float64] | None
    voltage_ns: NDArray[np.int64]
    voltage_v: NDArray[np.float64]
    terminal_v: NDArray[np.float64] | None
    markers: tuple[Marker, ...]
    notes: tuple[str, ...] = ()
