"""meshcat's web + ZeroMQ server in a child process bound to 127.0.0.1, that never outlives its owner.

The child runs `_SERVER_SCRIPT` (meshcat's ``ZMQWebSocketBridge`` listening on the loopback address
only), prints its URLs, and exits on end-of-file on its standard input: when `MeshcatServer.close`
is called, when the server object is garbage collected, and when this process ends in any way.
"""

from __future__ import annotations

import select
import subprocess
import sys
import tempfile
import time
import weakref
from typing import Sequence

import numpy as np

from ..errors import IdapbcError

__all__ = ["SERVER_MARKER", "MeshcatServer"]

_SERVER_SCRIPT = r"""# idapbc-pin meshcat server
import os, sys, threading
import tornado.web
from meshcat.servers import zmqserver as z

class LoopbackApp(tornado.web.Application):
    def listen(self, port, address="127.0.0.1", **kwargs):
        return super().listen(port, address=address, **kwargs)

class Bridge(z.ZMQWebSocketBridge):
    def make_app(self):
        return LoopbackApp([
            (r"/static/(.*)", z.StaticFileHandlerNoCache, {"path": z.VIEWER_ROOT, "default_filename": z.VIEWER_HTML}),
            (r"/", z.WebSocketHandler, {"bridge": self}),
        ])

def watch_parent():
    sys.stdin.buffer.read()  # EOF once the parent is gone, however it ended
    os._exit(0)

port = int(sys.argv[1]) if sys.argv[1] else None
try:
    bridge = Bridge(port=port)
except OSError as exc:
    print("error=" + str(exc).replace("\n", " "), flush=True)
    sys.exit(3)
threading.Thread(target=watch_parent, daemon=True).start()
print("zmq_url=" + bridge.zmq_url, flush=True)
print("web_url=" + bridge.web_url, flush=True)
os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
try:
    bridge.run()
except KeyboardInterrupt:
    pass
"""

#: Marker in the server's command line (tests look for leftover processes with it).
SERVER_MARKER = "# idapbc-pin meshcat server"


def _stop_process(proc: subprocess.Popen, stdin, log) -> None:
    """Close the child's standard input (it exits on EOF), kill it if still running, reap it."""
    try:
        if stdin is not None and not stdin.closed:
            stdin.close()
    except OSError:
        pass
    if proc.poll() is None:
        proc.kill()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:  # pragma: no cover - kill does not fail on Linux
        pass
    for stream in (proc.stdout, log):
        try:
            stream.close()
        except Exception:
            pass


class MeshcatServer:
    """meshcat's web + ZeroMQ server in a child process, bound to 127.0.0.1.

    Parameters
    ----------
    port : HTTP port of the viewer page ``http://127.0.0.1:<port>/static/``. None: the first
        free port from 7000. A port in use raises `IdapbcError`.
    timeout : seconds to wait for the server to start.

    The child process ends on `close`, on garbage collection, at interpreter exit, and when this
    process dies (it exits on end-of-file on its standard input).
    """

    def __init__(self, port: int | None = None, timeout: float = 30.0):
        import zmq

        if port is not None and not (isinstance(port, (int, np.integer)) and 0 < int(port) < 65536):
            raise IdapbcError(f"port must be an integer in 1..65535, got {port!r}. Fix: pass e.g. --port 7000, or omit it.")
        self._log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(
            [sys.executable, "-u", "-c", _SERVER_SCRIPT, "" if port is None else str(int(port))],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            start_new_session=True,
        )
        self._finalizer = weakref.finalize(self, _stop_process, self.proc, self.proc.stdin, self._log)
        lines = self._handshake(port, timeout)
        self.zmq_url = lines["zmq_url"]
        #: The viewer page, e.g. ``http://127.0.0.1:7000/static/``.
        self.url = lines["web_url"]
        self.port = int(self.url.rsplit(":", 1)[1].split("/", 1)[0])
        self.pid = self.proc.pid
        self._socket = zmq.Context.instance().socket(zmq.REQ)
        for opt, val in ((zmq.RCVTIMEO, int(timeout * 1000)), (zmq.SNDTIMEO, int(timeout * 1000)), (zmq.LINGER, 0)):
            self._socket.setsockopt(opt, val)
        self._socket.connect(self.zmq_url)

    def _handshake(self, port: int | None, timeout: float) -> dict[str, str]:
        """The ``key=value`` lines the child prints at start (zmq_url, web_url); on failure the child
        is stopped and `IdapbcError` says why."""
        lines: dict[str, str] = {}
        deadline = time.monotonic() + timeout
        while "web_url" not in lines:
            left = deadline - time.monotonic()
            ready = select.select([self.proc.stdout], [], [], max(0.0, left))[0] if left > 0 else []
            if not ready:
                self.close()
                raise IdapbcError(f"the meshcat server did not start within {timeout:g} s. Fix: check that meshcat is installed (pip install meshcat).")
            line = self.proc.stdout.readline().decode("utf-8", "replace").strip()
            if not line:  # EOF: the child exited
                self.proc.wait(timeout=10)
                err = self._stderr_tail()
                self.close()
                raise IdapbcError(f"the meshcat server exited at start (status {self.proc.returncode}): {err}. Fix: reinstall meshcat (pip install meshcat).")
            key, sep, value = line.partition("=")
            if sep and key == "error":
                self.close()
                if "in use" in value or "Errno 98" in value:
                    raise IdapbcError(f"port {port} is already in use ({value}). Fix: pass another --port, or omit it to pick a free one.")
                raise IdapbcError(f"the meshcat server could not listen on port {port}: {value}. Fix: pass another --port, or omit it.")
            if sep:
                lines[key] = value
        return lines

    def _stderr_tail(self) -> str:
        try:
            self._log.seek(0)
            text = self._log.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return "no message"
        return text.splitlines()[-1] if text else "no message"

    @property
    def alive(self) -> bool:
        """True while the server process runs."""
        return self.proc.poll() is None

    def send(self, frames: Sequence[bytes]) -> None:
        """Send one meshcat command (type, path, msgpack data) and wait for the server's reply."""
        import zmq

        if not self.alive:
            raise IdapbcError("the meshcat server is not running. Fix: call serve() again.")
        try:
            self._socket.send_multipart(list(frames))
            reply = self._socket.recv()
        except zmq.error.Again:
            raise IdapbcError("the meshcat server did not answer. Fix: close the viewer and serve again.") from None
        if reply != b"ok":
            raise RuntimeError(f"meshcat server replied {reply!r}")

    def scene_html(self) -> str:
        """The server's own standalone HTML of its current scene (meshcat's ``static_html()``)."""
        import zmq

        try:
            self._socket.send(b"get_scene")
            return self._socket.recv().decode("utf-8")
        except zmq.error.Again:
            raise IdapbcError("the meshcat server did not answer. Fix: close the viewer and serve again.") from None

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        sock = getattr(self, "_socket", None)
        if sock is not None:
            sock.close(linger=0)
            self._socket = None
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __repr__(self) -> str:
        state = f"serving {self.url}" if self.alive else "closed"
        return f"MeshcatServer(pid={self.proc.pid}, {state})"
