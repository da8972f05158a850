"""Live streams for tests: real local servers (ffmpeg in real time, sockets that refuse, hang or
stall), and videos to stream."""

from __future__ import annotations

import contextlib
import socket
import subprocess
import threading
from collections.abc import Callable
from functools import partial
from pathlib import Path

import cv2
import numpy as np

from waiting import listening, wait_until


def write_video(path: Path, n: int, fps: float, size=(96, 64)) -> Path:
    """A video whose frame i is uniformly grey at level 10 * i (modulo 250)."""
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert w.isOpened()
    for i in range(n):
        w.write(np.full((size[1], size[0], 3), (10 * i) % 250, np.uint8))
    w.release()
    return path


def ffmpeg() -> str:
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def free_port() -> int:
    """A TCP port nothing listens on: connecting to it is refused."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve(
    video: Path, port: int, name: str = "live", codec: str = "mpeg1video"
) -> subprocess.Popen:
    """ffmpeg serving ``video`` in a loop, in real time, as MPEG-TS over HTTP to one client
    (codec mpeg4 for frame rates MPEG-1 does not have, such as 5 fps)."""
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-re",
        "-stream_loop",
        "-1",
        "-i",
        str(video),
        "-an",
        "-c:v",
        codec,
        "-q:v",
        "4",
        "-f",
        "mpegts",
        "-listen",
        "1",
        f"http://127.0.0.1:{port}/{name}.ts",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait_serving(servers: list[subprocess.Popen], ports: list[int]) -> None:
    """Wait until each ffmpeg listens on its port, so that a camera connects at its first try;
    if one does not, stop them all and fail."""
    try:
        for server, port in zip(servers, ports, strict=True):
            wait_until(partial(_up, server, port), f"ffmpeg on port {port}")
            assert server.poll() is None, f"ffmpeg exited with {server.returncode} before serving"
    except BaseException:
        stop(servers)
        raise


def stop(servers: list[subprocess.Popen]) -> None:
    for server in servers:
        server.kill()
        server.wait()


def _up(server: subprocess.Popen, port: int) -> bool:
    return listening(port, taken=True) or server.poll() is not None


def transport_stream(video: Path, out: Path) -> bytes:
    """``video`` encoded as an MPEG-TS file (what an HTTP camera sends), its bytes."""
    cmd = [
        ffmpeg(),
        "-loglevel",
        "error",
        "-y",
        "-i",
        str(video),
        "-an",
        "-c:v",
        "mpeg1video",
        "-q:v",
        "4",
        "-f",
        "mpegts",
        str(out),
    ]
    subprocess.run(cmd, check=True, timeout=60)
    return out.read_bytes()


class StallingServer:
    """An HTTP server on 127.0.0.1 that answers each client with `body` and then holds the
    connection open, sending nothing more (a camera that hangs); body b"" hangs at once, before
    even a status line. close() ends it and every connection."""

    def __init__(self, body: bytes = b"") -> None:
        self.body = body
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.sock.settimeout(0.05)  # so that the accepting thread sees close() soon
        self.port = self.sock.getsockname()[1]
        self.clients: list[socket.socket] = []
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def url(self, name: str = "live") -> str:
        return f"http://127.0.0.1:{self.port}/{name}.ts"

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self.sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.clients.append(client)
            if self.body:
                threading.Thread(target=self._send, args=(client,), daemon=True).start()

    def _send(self, client: socket.socket) -> None:
        head = b"HTTP/1.1 200 OK\r\nContent-Type: video/mp2t\r\nConnection: close\r\n\r\n"
        with contextlib.suppress(OSError):  # the client left
            client.sendall(head + self.body)

    def close(self) -> None:
        self._closed.set()
        self._thread.join(timeout=5)
        self.sock.close()
        for c in self.clients:
            c.close()

    def __enter__(self) -> StallingServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def served_until(
    make: Callable[[], subprocess.Popen], done: Callable[[], bool], what: str, timeout_s: float
) -> subprocess.Popen:
    """A stream served by ``make()`` until ``done()``: each ffmpeg serves one client, where a
    camera answers every try, so one that ends before (a try of the service that gave up while
    the machine was busy) is served again. Returns the server serving at the end."""
    server = make()

    def check() -> bool:
        nonlocal server
        if done():
            return True
        if server.poll() is not None:
            server = make()
        return False

    wait_until(check, what, timeout_s=timeout_s, poll_s=0.2)
    return server
