"""The client side of the Foxglove WebSocket protocol v1 (subprotocol "foxglove.websocket.v1"; the
foxglove-sdk 0.30 server asks for "foxglove.sdk.v1", the same messages), as far as the live-view
tests need it: connect, read the server's channel advertisements, subscribe, and
decode the binary message-data frames (opcode 0x01: uint32 subscription id, uint64 log time in ns,
then the message; little endian). Written from the protocol's description, not from a client
library, so the tests check the server as any Foxglove app would see it."""

from __future__ import annotations

import json
import struct
import time
from typing import Any

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]  # the SDK 0.30 server names v1 "foxglove.sdk.v1"
MESSAGE_DATA = 0x01


class FoxgloveClient:
    def __init__(self, url: str, timeout_s: float = 30.0) -> None:
        from websockets.sync.client import connect

        self.ws = connect(url, subprotocols=SUBPROTOCOLS, open_timeout=timeout_s)  # type: ignore[list-item]
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> its advertisement
        self.server_info: dict[str, Any] = {}
        self._subs: dict[int, str] = {}  # subscription id -> topic
        self._data: list[tuple[str, int, Any]] = []  # message data read, not yet returned

    def _handle_text(self, text: str) -> None:
        msg = json.loads(text)
        if msg.get("op") == "serverInfo":
            self.server_info = msg
        elif msg.get("op") == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["topic"]] = ch

    def _read_until(self, done: Any, timeout_s: float, what: Any) -> None:
        """Read frames (advertisements; message data, kept in order) until `done()`; TimeoutError
        saying `what()` after `timeout_s`."""
        end = time.monotonic() + timeout_s
        while not done():
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(what())
            frame = self.ws.recv(timeout=left)
            if isinstance(frame, str):
                self._handle_text(frame)
            elif frame[0] == MESSAGE_DATA:
                sub_id, log_ns = struct.unpack_from("<IQ", frame, 1)
                self._data.append((self._subs[sub_id], log_ns, json.loads(frame[13:])))

    def wait_for_channels(self, topics: set[str], timeout_s: float = 30.0) -> None:
        """Read the server's frames until every one of `topics` is advertised."""
        self._read_until(lambda: topics <= set(self.channels), timeout_s,
                         lambda: f"advertised {sorted(self.channels)}, not all of {sorted(topics)}")  # fmt: skip

    def subscribe(self, topics: list[str]) -> None:
        subs = []
        for topic in topics:
            sub_id = len(self._subs) + 1
            self._subs[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def messages(self, count: int, timeout_s: float = 30.0) -> list[tuple[str, int, Any]]:
        """The next `count` message-data frames: (topic, log time ns, the JSON message)."""
        self._read_until(lambda: len(self._data) >= count, timeout_s, lambda: f"{len(self._data)} of {count} messages")
        got, self._data = self._data[:count], self._data[count:]
        return got

    def close(self) -> None:
        self.ws.close()
