"""A fake sync box on a pty pair: the driver opens `box.port` exactly like /dev/ttyACM0.

The box clock runs with its own offset and drift; lamp switches are reported as MARK lines
and passed to `on_lamp(state, host_monotonic_s)` (the simulated rig draws the lamp with it).
"""
from __future__ import annotations

import os
import random
import threading
import time
import tty
from typing import Callable


class FakeSyncBox:
    def __init__(self, clock_offset_s: float = 1000.0, drift_ppm: float = 30.0,
                 on_lamp: Callable[[int, float], None] | None = None, serial_number: str = "SB0001"):
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave
        self.offset, self.drift = clock_offset_s, drift_ppm * 1e-6
        self.on_lamp = on_lamp
        self.serial_number = serial_number
        self.t0 = time.monotonic()
        self.n = 0
        self.switches: list[tuple[int, float]] = []       # (state, true host monotonic s)
        self._stop = threading.Event()
        self._pulse: threading.Thread | None = None
        self._pulse_stop = threading.Event()
        self._write_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def box_us(self, host_s: float | None = None) -> int:
        t = time.monotonic() if host_s is None else host_s
        return int(((t - self.t0) * (1 + self.drift) + self.offset) * 1e6)

    def _send(self, line: str) -> None:
        with self._write_lock:
            os.write(self.master, (line + "\n").encode())

    def _run(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                data = os.read(self.master, 256)
            except OSError:
                return
            t = time.monotonic()
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                self._handle(line.decode().strip().split(), t)

    def _handle(self, parts: list[str], t: float) -> None:
        if not parts:
            return
        cmd = parts[0]
        if cmd == "HELLO":
            self._send(f"SYNCBOX 1.0 {self.serial_number}")
        elif cmd == "PING" and len(parts) == 2:
            self._send(f"PONG {parts[1]} {self.box_us(t)}")
        elif cmd == "LAMP" and len(parts) == 2:
            self._send("OK")
            self.switch(int(parts[1]))
        elif cmd == "START" and len(parts) == 3:
            self._send("OK")
            self._start(int(parts[1]) / 1000, int(parts[2]) / 1000)
        elif cmd == "STOP":
            self._pulse_stop.set()
            self._send("OK")
        else:
            self._send(f"ERR unknown command {' '.join(parts)!r}")

    def switch(self, state: int) -> None:
        t = time.monotonic()
        self.n += 1
        self.switches.append((state, t))
        if self.on_lamp:
            self.on_lamp(state, t)
        self._send(f"MARK {self.n} {self.box_us(t)} {state}")

    def _start(self, period_s: float, on_s: float) -> None:
        self._pulse_stop.set()
        if self._pulse:
            self._pulse.join()
        self._pulse_stop = stop = threading.Event()

        rng = random.Random(self.n)

        def pulse():
            while not stop.wait(period_s * rng.uniform(0.6, 1.4) - on_s):
                self.switch(1)
                if stop.wait(on_s):
                    break
                self.switch(0)
        self._pulse = threading.Thread(target=pulse, daemon=True)
        self._pulse.start()

    def close(self) -> None:
        self._stop.set()
        self._pulse_stop.set()
        os.close(self.master)
        os.close(self._slave)
