"""A small client of the foxglove.websocket.v1 protocol (websockets + protobuf), written from the
protocol's specification: it reads the server's advertisements, subscribes, and decodes each
binary Message Data frame with the protobuf schema the server advertised for its channel.

foxglove-sdk's server names the protocol ``foxglove.sdk.v1`` (the same messages: Foxglove renamed
it) and refuses the handshake without that name, so the client offers both names."""

from __future__ import annotations

import base64
import json
import struct
import time
from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import ClientConnection, connect
from websockets.typing import Subprotocol

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
OP_MESSAGE_DATA = 0x01
UNKNOWN_CHANNEL = "Unknown channel ID: "  # foxglove-sdk's status for a subscription to a channel it lacks


@dataclass(frozen=True)
class Channel:
    id: int
    topic: str
    encoding: str
    schema_name: str
    schema: str
    schema_encoding: str


class FoxgloveClient:
    def __init__(self, port: int, *, timeout_s: float = 10.0) -> None:
        self._connection = connect(
            f"ws://127.0.0.1:{port}",
            subprotocols=[Subprotocol(p) for p in SUBPROTOCOLS],
            proxy=None,
            max_size=64 << 20,
            open_timeout=timeout_s,
            # A client that stopped reading (websockets stops reading the socket once 16 messages
            # wait) never sees the server's close frame: closing it waits this long, not 10 s.
            close_timeout=1.0,
        )
        self.ws: ClientConnection = self._connection.__enter__()
        assert self.ws.subprotocol in SUBPROTOCOLS
        self.channels: dict[str, Channel] = {}
        self.server_info: dict[str, Any] | None = None
        self._subs: dict[int, Channel] = {}
        self._classes: dict[int, Any] = {}

    def close(self) -> None:
        self._connection.__exit__(None, None, None)

    def _handle_text(self, text: str) -> None:
        doc = json.loads(text)
        if doc["op"] == "serverInfo":
            self.server_info = doc
        elif doc["op"] == "advertise":
            for c in doc["channels"]:
                ch = Channel(
                    c["id"],
                    c["topic"],
                    c["encoding"],
                    c["schemaName"],
                    c["schema"],
                    c.get("schemaEncoding", ""),
                )
                self.channels[ch.topic] = ch
        elif doc["op"] == "status" and doc["message"].startswith(UNKNOWN_CHANNEL):
            self._subscribe_again(int(doc["message"].removeprefix(UNKNOWN_CHANNEL)))

    def _subscribe_again(self, channel_id: int) -> None:
        """foxglove-sdk sends a channel's advertisement before it adds the channel to the
        viewer's (connected_client.rs, ``advertise_channels``): a subscription sent at once can
        find it missing and be answered "Unknown channel ID". A viewer subscribes again."""
        subs = [{"id": k, "channelId": ch.id} for k, ch in self._subs.items() if ch.id == channel_id]
        if subs:
            self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def wait_for_topics(self, topics: list[str], timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not all(t in self.channels for t in topics):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(
                    f"not advertised within {timeout_s} s: {set(topics) - set(self.channels)}"
                )
            try:
                frame = self.ws.recv(timeout=remaining)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                self._handle_text(frame)

    def subscribe(self, topics: list[str]) -> None:
        self.wait_for_topics(topics)
        subs = []
        for topic in topics:
            sub_id = len(self._subs) + 1
            self._subs[sub_id] = self.channels[topic]
            subs.append({"id": sub_id, "channelId": self.channels[topic].id})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def _message_class(self, ch: Channel) -> Any:
        cls = self._classes.get(ch.id)
        if cls is None:
            assert ch.encoding == "protobuf" and ch.schema_encoding in ("protobuf", "")
            files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch.schema))
            pool = descriptor_pool.DescriptorPool()
            for fd in files.file:
                pool.Add(fd)
            cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(ch.schema_name))
            self._classes[ch.id] = cls
        return cls

    def next_message(self, timeout_s: float = 10.0) -> tuple[str, int, Any]:
        """(topic, log time ns, decoded message) of the next Message Data frame."""
        deadline = time.monotonic() + timeout_s
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError("no message data")
            frame = self.ws.recv(timeout=remaining)
            if isinstance(frame, str):
                self._handle_text(frame)
                continue
            if frame[0] != OP_MESSAGE_DATA:
                continue
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            ch = self._subs[sub_id]
            payload = frame[13:]
            if ch.encoding == "json":
                return ch.topic, log_time, json.loads(payload)
            return ch.topic, log_time, self._message_class(ch).FromString(payload)
