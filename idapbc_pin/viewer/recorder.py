"""A meshcat scene recorded in this process, through meshcat's own server logic (no server process).

Every command a ``meshcat.Visualizer`` sends goes through ``ZMQWebSocketBridge.handle_zmq`` on an
in-memory scene tree, so the standalone HTML (``Visualizer.static_html()``) is exactly what
meshcat's server would return, and the commands are kept in order to replay into a live server.
"""

from __future__ import annotations

from ._meshcat import import_meshcat

__all__ = ["SceneRecorder"]


class _ReplySocket:
    """Stands in for the server's ZeroMQ socket: keeps the last reply."""

    reply: bytes = b""

    def send(self, data: bytes) -> None:
        self.reply = data


class _BridgeState:
    """The state `meshcat.servers.zmqserver.ZMQWebSocketBridge.handle_zmq` works on, in memory."""

    def __init__(self):
        from meshcat.servers.tree import SceneTree

        self.tree = SceneTree()
        self.zmq_socket = _ReplySocket()
        self.websocket_pool: set = set()
        self.web_url = ""

    def forward_to_websockets(self, frames) -> None:  # no browsers in memory
        pass


class SceneRecorder:
    """A meshcat "window" (``meshcat.Visualizer(window=SceneRecorder())``) that records the scene.

    `get_scene` (what ``Visualizer.static_html()`` calls) returns the HTML meshcat's server would;
    `messages` holds every command as its ZeroMQ frames (type, path, msgpack data), in order.
    """

    def __init__(self):
        self._state = _BridgeState()
        self.messages: list[list[bytes]] = []
        self.web_url = None

    def _handle(self, frames: list[bytes]) -> bytes:
        ZMQWebSocketBridge = import_meshcat().servers.zmqserver.ZMQWebSocketBridge

        ZMQWebSocketBridge.handle_zmq(self._state, frames)
        return self._state.zmq_socket.reply

    def send(self, command) -> None:
        """Apply one meshcat command to the scene tree and record it."""
        import umsgpack

        data = command.lower()
        frames = [data["type"].encode("utf-8"), data["path"].encode("utf-8"), umsgpack.packb(data)]
        reply = self._handle(frames)
        if reply != b"ok":
            raise RuntimeError(f"meshcat rejected a {data['type']} command: {reply!r}")
        self.messages.append(frames)

    def get_scene(self) -> str:
        """meshcat's standalone HTML of the scene recorded so far."""
        return self._handle([b"get_scene"]).decode("utf-8")
