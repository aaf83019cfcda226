"""A loopback TCP server with the face of :class:`~gonio.sim.emulators.link.PtyLink`: an instrument that
talks raw SCPI over a socket (LAN instruments listen on port 5025), one client at a time.

:attr:`TcpLink.port` is ``host:port``; a client that connects replaces the previous one (an instrument
serves the last connection). :meth:`TcpLink.unplug` closes the client's connection and stops listening
(the instrument's network is gone: the driver's reads fail, its reconnects are refused);
:meth:`TcpLink.replug` listens again on the same port.
"""

from __future__ import annotations

import fcntl
import select
import socket
import struct
import termios
import threading
import time

from gonio.sim.emulators.link import Waker

__all__ = ["TcpLink"]


class TcpLink:
    """Parameters: ``host`` (a loopback address), ``port`` (0: any free port, kept across replugs)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        if host not in ("127.0.0.1", "localhost", "::1"):
            raise ValueError(f"TcpLink: host {host!r} is not a loopback address")
        self.host = host
        self._port = int(port)
        self._srv: socket.socket | None = None
        self._conn: socket.socket | None = None
        self._lock = threading.RLock()
        self._waker = Waker()   # a wait in readable() or read() ends at once on wake()
        self.replug()

    @property
    def port(self) -> str:
        return f"{self.host}:{self._port}"

    @property
    def tcp_port(self) -> int:
        return self._port

    def replug(self) -> None:
        with self._lock:
            self.unplug()
            srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            deadline = time.monotonic() + 1.0
            while True:
                try:
                    srv.bind((self.host, self._port))
                    break
                except OSError:
                    # The closed listener lives on while the serving thread's select() still holds it
                    # (at most one poll); bounded.
                    if time.monotonic() > deadline:
                        srv.close()
                        raise
                    time.sleep(0.005)
            srv.listen(1)
            srv.setblocking(False)
            self._port = srv.getsockname()[1]
            self._srv = srv

    def unplug(self) -> None:
        with self._lock:
            for s in (self._conn, self._srv):
                if s is not None:
                    try:
                        s.close()
                    except OSError:
                        pass
            self._conn = self._srv = None

    @property
    def plugged(self) -> bool:
        return self._srv is not None

    def _accept(self) -> None:
        try:
            conn, _ = self._srv.accept()
        except (BlockingIOError, OSError):
            return
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(1.0)  # reads come after select() says so; a write waits at most this long
        if self._conn is not None:
            self._conn.close()
        self._conn = conn

    def wake(self) -> None:
        """End a wait in :meth:`readable` or :meth:`read` now (the emulator thread is being stopped)."""
        self._waker.wake()

    def readable(self, timeout_s: float = 0.0) -> bool:
        srv, conn = self._srv, self._conn
        if srv is None:
            return False
        try:
            ready = select.select([s for s in (srv, conn) if s is not None] + [self._waker.fd], [], [],
                                  timeout_s)[0]
            if self._waker.fd in ready:
                self._waker.clear()
                return False
        except (OSError, ValueError):
            return False
        if srv in ready:
            with self._lock:
                if self._srv is srv:
                    self._accept()
        return conn is not None and conn in ready

    def read(self, timeout_s: float) -> bytes:
        """Bytes the client sent, waiting at most ``timeout_s`` s (b"" when none, or unplugged)."""
        if not self.readable(timeout_s):
            return b""
        conn = self._conn
        if conn is None:
            return b""
        try:
            data = conn.recv(4096)
        except (BlockingIOError, InterruptedError, TimeoutError):
            return b""
        except OSError:
            data = b""
        if not data:  # the client closed its end
            with self._lock:
                if self._conn is conn:
                    conn.close()
                    self._conn = None
        return data

    def pending(self) -> int:
        """Bytes written that the client's end has not acknowledged (the socket's send queue; what the
        client's program has not read yet cannot be seen from here)."""
        conn = self._conn
        if conn is None:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(conn.fileno(), termios.TIOCOUTQ, b"\0\0\0\0"))[0]
        except OSError:
            return 0

    def write(self, data: bytes) -> None:
        conn = self._conn
        if conn is None or not data:
            return
        try:
            conn.sendall(data)  # blocking, at most the connection's 1 s time-out
        except OSError:
            return

    def close(self) -> None:
        self.unplug()
        self._waker.close()
