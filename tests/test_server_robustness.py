"""The status server against hostile or careless clients, over real sockets."""
import http.client
import socket
import statistics
import struct
import threading
import time

import numpy as np
import pytest

import server
from recon.live.publish import LivePublisher
from server.app import MAX_CONNECTIONS
from server.handler import StatusHandler

SECRET = b"top secret: never served"


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """A run folder with renders, and secrets beside it and inside it outside the whitelist."""
    root = tmp_path_factory.mktemp("srv_robust")
    (root / "secret.txt").write_bytes(SECRET)
    run = root / "run"
    pub = LivePublisher(run)
    pub.status({"state": "training", "iteration": 7})
    pub.renders(0.5, np.zeros((8, 8, 3), np.uint8), np.full((8, 8), 300.0), 290.0, 310.0)
    (run / "secret.txt").write_bytes(SECRET)
    (run / "live" / "secret.txt").write_bytes(SECRET)
    (run / "live" / "render" / "latest" / "secret.txt").write_bytes(SECRET)
    return root


@pytest.fixture(scope="module")
def handle(tree):
    h = server.serve("127.0.0.1", 0, run_dir=tree / "run")
    yield h
    h.stop()


def raw(handle, data: bytes, timeout=5.0) -> bytes:
    """Send bytes, read until the server closes (requests here say Connection: close or get errors)."""
    with socket.create_connection((handle.host, handle.port), timeout=timeout) as s:
        s.sendall(data)
        chunks = []
        while chunk := s.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def status_of(response: bytes) -> int:
    assert response.startswith(b"HTTP/1."), response[:100]
    return int(response.split(b" ", 2)[1])


def request(path: str, extra: str = "") -> bytes:
    return f"GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n{extra}\r\n".encode("latin-1")


def alive(handle) -> bool:
    return status_of(raw(handle, request("/api/status"))) == 200


@pytest.mark.parametrize("path", [
    "/../secret.txt", "/../../../../etc/passwd", "/render/../../secret.txt", "/render/latest/../../secret.txt",
    "/%2e%2e/secret.txt", "/%2E%2E/%2E%2E/etc/passwd", "/render/latest/..%2f..%2f..%2fsecret.txt",
    "/render/%2e%2e/%2e%2e/secret.txt", "/render/latest/%2e%2e", "/render\\..\\..\\secret.txt",
    "/render/latest/rgb.png%00.txt", "/%252e%252e/secret.txt",
    "//etc/passwd", "/etc/passwd", "/secret.txt", "/live/secret.txt", "/live/status.json",
    "/render/latest/secret.txt", "/render/latest/", "/render/latest", "/render//rgb.png",
    "http://evil.example/../secret.txt", "/api/../secret.txt", "/api/%2e%2e/secret.txt",
    "/%ff%fe/secret.txt", "/api/metrics?" + "&".join(["a=1"] * 20),
])
def test_path_traversal_is_refused(handle, path):
    response = raw(handle, request(path))
    assert status_of(response) in (400, 404), response[:200]
    assert SECRET not in response and b"root:" not in response


def test_absolute_form_target_for_a_real_file_is_served_by_its_path_only(handle):
    assert status_of(raw(handle, request("http://127.0.0.1/api/status"))) == 200


def test_a_long_request_line_is_414(handle):
    assert status_of(raw(handle, request("/" + "a" * 10_000))) == 414
    assert alive(handle)


def test_a_large_header_block_is_431(handle):
    headers = "".join(f"X-Filler-{i}: {'b' * 900}\r\n" for i in range(30))    # 27 KiB of headers
    assert status_of(raw(handle, request("/api/status", headers))) == 431
    assert status_of(raw(handle, request("/api/status", f"X-Long: {'c' * 70_000}\r\n"))) == 431
    assert alive(handle)


def test_a_request_body_is_413(handle):
    response = raw(handle, request("/api/status", "Content-Length: 1000000000\r\n"))
    assert status_of(response) == 413
    chunked = raw(handle, request("/api/status", "Transfer-Encoding: chunked\r\n") + b"5\r\nhello\r\n0\r\n\r\n")
    assert status_of(chunked) == 413
    assert alive(handle)


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "OPTIONS", "PATCH", "TRACE", "CONNECT"])
def test_only_get_and_head(handle, method):
    response = raw(handle, f"{method} /api/status HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nhello".encode())
    assert status_of(response) == 405 and b"Allow: GET, HEAD" in response


def test_garbage_gets_400_and_the_server_goes_on(handle):
    tls_hello = bytes.fromhex("16030100a5010000a10303") + bytes(200) + b"\r\n\r\n"   # (without a newline: idle timeout)
    for junk in (tls_hello, b"\x00\x01\x02 garbage\r\n\r\n", b"GET\r\n\r\n", b"GET / HTTP/9.9\r\n\r\n"):
        response = raw(handle, junk)
        assert status_of(response) in (400, 505), response[:120]
    assert alive(handle) and handle.counts["errors"] == 0


def test_a_client_vanishing_mid_download_is_survived(handle, tree):
    big = tree / "run" / "live" / "render" / "t63"
    big.mkdir(parents=True, exist_ok=True)
    (big / "kelvin.npy").write_bytes(bytes(48 << 20))          # far more than the socket buffers hold
    before = handle.counts["disconnects"]
    for _ in range(3):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        s.connect((handle.host, handle.port))
        s.sendall(request("/render/t63/kelvin.npy"))
        assert s.recv(1024).startswith(b"HTTP/1.1 200")
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))   # reset, not FIN
        s.close()
    deadline = time.monotonic() + 10
    while handle.counts["disconnects"] < before + 3:
        assert time.monotonic() < deadline, handle.counts
        time.sleep(0.05)
    assert alive(handle) and handle.counts["errors"] == 0


def test_too_many_connections_are_refused_then_served_again(handle):
    idle = [socket.create_connection((handle.host, handle.port)) for _ in range(MAX_CONNECTIONS)]
    try:
        time.sleep(0.3)                                  # let the server accept them all
        response = raw(handle, request("/api/status"))
        assert status_of(response) == 503
    finally:
        for s in idle:
            s.close()
    deadline = time.monotonic() + 5
    while not alive(handle):
        assert time.monotonic() < deadline
        time.sleep(0.05)


def test_an_idle_connection_is_dropped(tree, monkeypatch):
    monkeypatch.setattr(StatusHandler, "timeout", 0.3)
    with server.serve("127.0.0.1", 0, run_dir=tree / "run") as h:
        with socket.create_connection((h.host, h.port), timeout=5) as s:
            t0 = time.monotonic()
            assert s.recv(100) == b""                    # closed by the server, not by our timeout
            assert time.monotonic() - t0 < 3


def test_keep_alive_connection_serves_many_requests(handle):
    conn = http.client.HTTPConnection(handle.host, handle.port, timeout=5)
    for _ in range(20):
        conn.request("GET", "/api/status")
        r = conn.getresponse()
        assert r.status == 200 and r.getheader("Connection") is None
        r.read()
    conn.close()


def test_stop_ends_open_keep_alive_connections(tree):
    h = server.serve("127.0.0.1", 0, run_dir=tree / "run")
    conn = http.client.HTTPConnection(h.host, h.port, timeout=5)
    conn.request("GET", "/api/status")
    conn.getresponse().read()
    h.stop()
    with pytest.raises((ConnectionError, http.client.HTTPException, OSError)):
        conn.request("GET", "/api/status")
        conn.getresponse().read()


def test_latency_stays_low_beside_a_cpu_bound_thread(handle):
    """Loose sanity bound only; bench/server_latency.py measures the figure (p95 < 100 ms)."""
    stop = threading.Event()

    def spin():
        x = 0
        while not stop.is_set():
            for i in range(5000):
                x += i * i

    t = threading.Thread(target=spin, daemon=True)
    t.start()
    conn = http.client.HTTPConnection(handle.host, handle.port, timeout=5)
    times = []
    try:
        for path in ["/api/status", "/api/renders", "/render/latest/rgb.png", "/"] * 15:
            t0 = time.perf_counter()
            conn.request("GET", path)
            conn.getresponse().read()
            times.append(time.perf_counter() - t0)
    finally:
        stop.set()
        t.join()
        conn.close()
    p95 = statistics.quantiles(times, n=20)[-1]
    assert p95 < 0.5, f"p95 {p95 * 1e3:.0f} ms"
