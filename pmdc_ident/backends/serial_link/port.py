"""The transport: one serial port, opened exclusively, frames written whole, bytes read.

A pseudo-terminal (a virtual board) is reopened only while it is the same terminal:
the kernel hands a freed ``/dev/pts/N`` to the next program that asks for one (``ros2
launch`` gives each node a pty), and a reconnecting driver must not write its handshake
into another program's terminal.
"""

from __future__ import annotations

import os
import select
import threading
import time

import serial

from pmdc_ident.backends.base import BackendError
from pmdc_ident.backends.serial_link.errors import LinkLostError, reason
from pmdc_ident.protocol import Message, frame_message

__all__ = ["WRITE_STALL_S", "SerialPort", "pty_identity"]

WRITE_STALL_S = 0.5  # a port that accepts no byte for this long (while waited for) failed


class SerialPort:
    """The pyserial port of one board: open and close, numbered frames out, bytes in.

    Reading and opening raise :class:`LinkLostError` (the link is gone); sending raises
    :class:`BackendError` (the caller's command failed). One writer at a time.
    """

    def __init__(self, name: str, baud: int) -> None:
        self.name = name
        self.baud = baud
        self.last_write_s = 0.0  # time.monotonic() of the last frame written whole
        self._ser: serial.Serial | None = None
        self._pty: tuple[int, int] | None = None  # the pseudo-terminal first opened
        self._write_lock = threading.Lock()
        self._seq = 0

    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def fileno(self) -> int:
        """The open port's file descriptor."""
        ser = self._ser
        if ser is None:
            msg = f"serial port {self.name} is not open"
            raise BackendError(msg)
        return int(ser.fileno())

    def open(self) -> None:
        """Open the port (closing any previous one); raises LinkLostError."""
        self.close()
        pty = pty_identity(self.name)
        if self._pty is None:
            self._pty = pty
        elif pty is not None and pty != self._pty:
            msg = (
                f"{self.name} is now another program's terminal (the pseudo-terminal "
                "number was reused after the board closed it)"
            )
            raise LinkLostError(msg, fatal=True)
        try:
            self._ser = serial.Serial(self.name, self.baud, timeout=0.02, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            msg = f"cannot open serial port {self.name!r}: {reason(exc)}"
            raise LinkLostError(msg) from None

    def close(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail any way
                pass

    def discard_input(self) -> None:
        """Drop what waits in the input buffer (a handshake starts clean)."""
        ser = self._ser
        assert ser is not None
        try:
            ser.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            msg = f"serial port {self.name} failed: {reason(exc)}"
            raise LinkLostError(msg) from None

    def read(self) -> bytes:
        """What has arrived (waiting at most the port's 20 ms timeout for a byte)."""
        ser = self._ser
        if ser is None:
            msg = f"serial port {self.name} is closed"
            raise LinkLostError(msg)
        try:
            return bytes(ser.read(max(1, ser.in_waiting)))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            msg = f"serial port {self.name} failed: {reason(exc)} (board unplugged?)"
            raise LinkLostError(msg) from None

    def send(self, msg: Message) -> int:
        """Frame ``msg`` with the next sequence number and write it; returns the number."""
        ser = self._ser
        if ser is None:
            text = f"serial port {self.name} is not open"
            raise BackendError(text)
        with self._write_lock:
            self._seq = (self._seq + 1) & 0xFF
            seq = self._seq
            try:
                _write_all(ser, frame_message(msg, seq))
            except (serial.SerialException, OSError, TypeError, AttributeError, ValueError) as exc:
                text = f"serial port {self.name} write failed: {reason(exc)}"
                raise BackendError(text) from None
            self.last_write_s = time.monotonic()
        return seq


def _write_all(ser: serial.Serial, data: bytes) -> None:
    """Write every byte; time out only while the port itself refuses bytes.

    Not ``ser.write``: pyserial 3.5 raises 'Write timeout' after a complete write
    whenever the call as a whole took longer than its timeout, which a host starved
    of CPU for half a second (a busy machine) turns into a lost link. Here the
    port's file descriptor (non-blocking, as pyserial opens it) takes what it can,
    and only a port that takes nothing for ``WRITE_STALL_S`` of waiting is a
    failure (a wedged adapter)."""
    fd = ser.fileno()
    view = memoryview(data)
    while view:
        try:
            n = os.write(fd, view)
        except BlockingIOError:
            n = 0
        view = view[n:]
        if view and not select.select([], [fd], [], WRITE_STALL_S)[1]:
            msg = f"the port took no byte for {WRITE_STALL_S:g} s"
            raise serial.SerialTimeoutException(msg)


def pty_identity(port: str) -> tuple[int, int] | None:
    """(device, inode change time) of a pseudo-terminal; ``None`` for anything else.

    A reallocated ``/dev/pts/N`` has the same device number but a new inode."""
    path = os.path.realpath(port)
    if not path.startswith("/dev/pts/"):
        return None
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_rdev, st.st_ctime_ns
