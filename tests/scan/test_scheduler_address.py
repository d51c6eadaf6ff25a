"""``xray-viz scan --scheduler ADDR`` at the wrong kind of server, or a malformed address: one
line and exit 2, within a bounded time (issue 42).

Tiny socket servers on 127.0.0.1, each in a thread: an SSH-like one that sends its banner
(Dask read its first 8 bytes as a message length: a MemoryError for 2.82 EiB), an HTTP-like one
that says nothing until asked (Dask waited for its greeting for ever), one that closes at once;
and a real ``dask scheduler`` process, which is accepted.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from xray_viz.cli import main
from xray_viz.errors import SceneError

distributed = pytest.importorskip("distributed")


class _Server:
    """A TCP server on 127.0.0.1 in a thread: ``greeting`` sent on each connection (or none),
    the connection then held open (``hold``) or closed."""

    def __init__(self, greeting: bytes = b"", hold: bool = True):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.port = self.sock.getsockname()[1]
        self.greeting, self.hold, self.conns = greeting, hold, []
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            if self.greeting:
                conn.sendall(self.greeting)
            if self.hold:
                self.conns.append(conn)
            else:
                conn.close()

    def close(self):
        self.sock.close()
        for c in self.conns:
            c.close()


@pytest.fixture
def server():
    made = []

    def make(*args, **kwargs):
        made.append(_Server(*args, **kwargs))
        return made[-1]

    yield make
    for s in made:
        s.close()


def _scan(capsys, tmp_path, address) -> tuple[int, str, float]:
    t0 = time.monotonic()
    code = main(["scan", "sphere", "-o", str(tmp_path / "x.zarr"), "--projections", "2",
                 "--scheduler", address])
    err = capsys.readouterr().err
    return code, err, time.monotonic() - t0


@pytest.mark.parametrize("greeting, hold, words", [
    (b"SSH-2.0-OpenSSH_9.2p1 Debian-2+deb12u3\r\n", True, "an SSH server"),
    (b"HTTP/1.1 400 Bad Request\r\n\r\n", True, "not a Dask scheduler"),
    (b"", True, "no answer within 1 s"),                       # an HTTP server: waits to be asked
    (b"", False, "closed the connection"),
])
def test_scheduler_at_the_wrong_kind_of_server(server, capsys, tmp_path, monkeypatch,
                                               greeting, hold, words):
    import importlib

    monkeypatch.setattr(importlib.import_module("xray_viz.scan"), "SCHEDULER_TIMEOUT", 1.0)
    s = server(greeting, hold)
    code, err, took = _scan(capsys, tmp_path, f"tcp://127.0.0.1:{s.port}")
    assert code == 2 and words in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"127.0.0.1:{s.port}" in err
    assert took < 20
    assert not (tmp_path / "x.zarr").exists()


@pytest.mark.parametrize("address", ["http://127.0.0.1:8786", "127.0.0.1:87x86", "tcp://",
                                     "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "8786",
                                     "tcp://a b:8786"])
def test_malformed_scheduler_address(capsys, tmp_path, address):
    code, err, took = _scan(capsys, tmp_path, address)
    assert code == 2 and "not a Dask scheduler address; give tcp://HOST:PORT" in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_nothing_listens(capsys, tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]                 # closed again: nothing listens there
    code, err, took = _scan(capsys, tmp_path, f"tcp://127.0.0.1:{port}")
    assert code == 2 and "cannot connect" in err and "Traceback" not in err


def test_a_real_scheduler_is_accepted(tmp_path):
    """``dask scheduler`` on 127.0.0.1: its greeting passes the check (tcp:// added)."""
    from xray_viz.scan import check_scheduler

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([str(Path(sys.executable).parent / "dask"), "scheduler", "--host",
                             "127.0.0.1", "--port", str(port), "--no-dashboard"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 60
        while True:
            try:
                assert check_scheduler(f"127.0.0.1:{port}", timeout=5) == \
                    f"tcp://127.0.0.1:{port}"
                break
            except SceneError as exc:
                if "cannot connect" not in str(exc) or time.monotonic() > end:
                    raise
                time.sleep(0.3)
        with distributed.Client(f"tcp://127.0.0.1:{port}", timeout=30) as client:
            assert client.scheduler_info()["address"] == f"tcp://127.0.0.1:{port}"
    finally:
        proc.terminate()
        proc.wait(timeout=30)
