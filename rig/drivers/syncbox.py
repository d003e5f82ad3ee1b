"""Serial sync box: a microcontroller that switches a lamp (hot enough for the thermal camera,
bright for the phone) and reports each switch with its own microsecond clock.

Line protocol (ASCII, one command or report per line, 115200 baud):

    host -> box                       box -> host
    HELLO                             SYNCBOX <version> <serial>
    PING <seq>                        PONG <seq> <t_us>          (box clock when PING arrived)
    START <period_ms> <on_ms>         OK                         lamp pulses about every period_ms
    LAMP <0|1>                        OK                         one manual switch
    STOP                              OK
                                      MARK <n> <t_us> <0|1>      every lamp switch (unsolicited)
                                      ERR <text>

Pulse intervals vary pseudo-randomly within +-40 % of period_ms: a periodic train would match a
video at any whole number of periods. The box clock is mapped to the host's monotonic clock from PING round trips: the offset is
taken from the exchanges with the shortest round trip (the tightest bound), and a drift is fitted
once pings span time.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass

import numpy as np
import serial
import serial.tools.list_ports

log = logging.getLogger(__name__)

BAUD = 115200
# USB-serial chips a sync box is usually built on
KNOWN_VIDS = {0x2341: "Arduino", 0x2A03: "Arduino", 0x0403: "FTDI", 0x1A86: "WCH CH340",
              0x10C4: "Silicon Labs CP210x", 0x239A: "Adafruit", 0x2E8A: "Raspberry Pi RP2040"}


class SyncBoxError(RuntimeError):
    pass


@dataclass
class Marker:
    n: int
    box_us: int
    state: int            # 1 lamp on, 0 off
    host_ns: int          # host monotonic ns when the line arrived (upper bound of the true time)


class SyncBox:
    def __init__(self, port: str, baudrate: int = BAUD, timeout_s: float = 1.0):
        try:
            self.serial = serial.Serial(port, baudrate, timeout=0.1, exclusive=True)
        except serial.SerialException as exc:
            raise SyncBoxError(f"sync box {port}: {exc}") from exc
        self.port = port
        self.timeout_s = timeout_s
        self.markers: queue.Queue[Marker] = queue.Queue()
        self._replies: queue.Queue[str] = queue.Queue()
        self._pings: list[tuple[float, float, float]] = []   # (host mid s, box s, round trip s)
        self._seq = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read_loop, name="syncbox", daemon=True)
        self._reader.start()
        self.identity = self.command("HELLO", expect="SYNCBOX")

    def _read_loop(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                data = self.serial.read(max(1, self.serial.in_waiting))
            except (serial.SerialException, OSError, TypeError):
                if self._stop.is_set():
                    return
                time.sleep(0.05)
                continue
            now = time.monotonic_ns()
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                self._handle(line.decode("ascii", "replace").strip(), now)

    def _handle(self, line: str, now: int) -> None:
        parts = line.split()
        if not parts:
            return
        if parts[0] == "MARK" and len(parts) == 4:
            try:
                self.markers.put(Marker(int(parts[1]), int(parts[2]), int(parts[3]), now))
            except ValueError:
                log.warning("sync box: bad line %r", line)
            return
        self._replies.put(f"{line} @{now}")

    def command(self, line: str, expect: str = "OK") -> str:
        """Send one command and return its reply (without the arrival stamp)."""
        with self._lock:
            while not self._replies.empty():
                self._replies.get_nowait()
            self.serial.write((line + "\n").encode())
            deadline = time.monotonic() + self.timeout_s
            while (remaining := deadline - time.monotonic()) > 0:
                try:
                    reply = self._replies.get(timeout=remaining)
                except queue.Empty:
                    break
                text = reply.rsplit(" @", 1)[0]
                if text.startswith("ERR"):
                    raise SyncBoxError(f"sync box {self.port}: {line!r} -> {text}")
                if text.startswith(expect):
                    self._last_reply_ns = int(reply.rsplit(" @", 1)[1])
                    return text
            raise SyncBoxError(f"sync box {self.port}: no {expect} reply to {line!r} within {self.timeout_s} s")

    def ping(self) -> tuple[float, float, float]:
        """One clock exchange. -> (host mid-time s, box time s, round trip s)."""
        self._seq += 1
        t0 = time.monotonic_ns()
        reply = self.command(f"PING {self._seq}", expect=f"PONG {self._seq} ")
        t1 = self._last_reply_ns
        sample = ((t0 + t1) / 2e9, int(reply.split()[2]) / 1e6, (t1 - t0) / 1e9)
        self._pings.append(sample)
        return sample

    def clock(self) -> tuple[float, float]:
        """-> (rate, offset) with host_s = rate * box_s + offset, from the pings so far."""
        if not self._pings:
            raise SyncBoxError("no PING exchange yet")
        p = np.array(self._pings)
        best = p[p[:, 2] <= np.quantile(p[:, 2], 0.5)] if len(p) >= 4 else p
        if len(best) >= 3 and np.ptp(best[:, 1]) > 1.0:
            rate, offset = np.polyfit(best[:, 1], best[:, 0], 1)
            return float(rate), float(offset)
        i = int(np.argmin(p[:, 2]))
        return 1.0, float(p[i, 0] - p[i, 1])

    def box_to_host_s(self, box_us: int) -> float:
        rate, offset = self.clock()
        return rate * box_us / 1e6 + offset

    def start(self, period_s: float, on_s: float) -> None:
        self.command(f"START {round(period_s * 1000)} {round(on_s * 1000)}")

    def stop(self) -> None:
        self.command("STOP")

    def close(self) -> None:
        try:
            self.stop()
        except (SyncBoxError, serial.SerialException, OSError):
            pass
        self._stop.set()
        self.serial.close()
        self._reader.join(timeout=1)


def list_serial_ports() -> list[dict]:
    """Serial ports with USB ids; `likely_syncbox` for chips sync boxes are built on."""
    out = []
    for p in serial.tools.list_ports.comports():
        out.append({"port": p.device, "description": p.description, "vid": p.vid, "pid": p.pid,
                    "serial_number": p.serial_number,
                    "chip": KNOWN_VIDS.get(p.vid) if p.vid is not None else None,
                    "likely_syncbox": p.vid in KNOWN_VIDS})
    return out
