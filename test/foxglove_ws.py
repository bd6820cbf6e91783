"""A Foxglove WebSocket client for the tests and benchmarks/live_view.py: the ``websockets``
package speaking the subprotocol ``foxglove.sdk.v1`` (foxglove-sdk's server refuses a client
that offers only ``foxglove.websocket.v1``). It reads the server's channel advertisements,
subscribes, and decodes message data: JSON channels with json, protobuf channels (foxglove's
typed schemas) from the advertised FileDescriptorSet with google.protobuf."""

from __future__ import annotations

import base64
import contextlib
import json
import struct
import time
from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.json_format import MessageToDict
from websockets.sync.client import ClientConnection, connect

SUBPROTOCOL = 'foxglove.sdk.v1'
#: Binary opcode of message data (server → client).
MESSAGE_DATA = 0x01


@dataclass(frozen=True)
class Received:
    """One message: its channel's topic, the decoded message (a dict), the server's log time
    (ns) and when this client received it (time.time(), s)."""

    topic: str
    message: dict[str, Any]
    log_time_ns: int
    received: float


class FoxgloveClient:
    """Connected to ``url``; :attr:`channels` {topic: advertised channel} as advertised."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        self._stack = contextlib.ExitStack()
        self.ws: ClientConnection = self._stack.enter_context(
            connect(url, subprotocols=[SUBPROTOCOL], open_timeout=timeout, max_size=None))
        self.channels: dict[str, dict[str, Any]] = {}
        self.server_info: dict[str, Any] | None = None
        self._subscriptions: dict[int, dict[str, Any]] = {}
        self._decoders: dict[int, Any] = {}

    def _handle_text(self, text: str) -> None:
        doc = json.loads(text)
        if doc.get('op') == 'serverInfo':
            self.server_info = doc
        elif doc.get('op') == 'advertise':
            for channel in doc['channels']:
                self.channels[channel['topic']] = channel

    def receive(self, timeout: float) -> Received | None:
        """The next message data within ``timeout`` s (control messages are taken on the way),
        or None."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                frame = self.ws.recv(timeout=left)
            except TimeoutError:
                return None
            if isinstance(frame, str):
                self._handle_text(frame)
                continue
            if frame[0] != MESSAGE_DATA:
                continue
            sub_id, log_time = struct.unpack_from('<IQ', frame, 1)
            channel = self._subscriptions[sub_id]
            return Received(channel['topic'], self._decode(sub_id, frame[13:]), log_time,
                            time.time())
        return None

    def wait_channels(self, topics: list[str], timeout: float) -> None:
        """Until every topic of ``topics`` is advertised (TimeoutError naming the missing)."""
        deadline = time.monotonic() + timeout
        while not set(topics) <= set(self.channels):
            if time.monotonic() > deadline:
                raise TimeoutError(f'not advertised within {timeout} s: '
                                   f'{sorted(set(topics) - set(self.channels))}')
            try:
                frame = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                self._handle_text(frame)

    def subscribe(self, topics: list[str]) -> None:
        """Subscribe to advertised ``topics``."""
        subs = []
        for topic in topics:
            channel = self.channels[topic]
            sub_id = len(self._subscriptions) + 1
            self._subscriptions[sub_id] = channel
            self._decoders[sub_id] = _decoder(channel)
            subs.append({'id': sub_id, 'channelId': channel['id']})
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def _decode(self, sub_id: int, payload: bytes) -> dict[str, Any]:
        decoded: dict[str, Any] = self._decoders[sub_id](payload)
        return decoded

    def close(self) -> None:
        self._stack.close()

    def __enter__(self) -> FoxgloveClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _decoder(channel: dict[str, Any]) -> Any:
    """payload → dict for the channel's encoding (json, or protobuf from its schema)."""
    if channel['encoding'] == 'json':
        return json.loads
    if channel['encoding'] != 'protobuf':
        raise ValueError(f'{channel["topic"]}: no decoder for {channel["encoding"]}')
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel['schema']))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel['schemaName']))
    return lambda payload: MessageToDict(cls.FromString(payload),
                                         preserving_proto_field_name=True,
                                         always_print_fields_with_no_presence=True)


def as_dict(message: Any) -> dict[str, Any]:
    """A foxglove-sdk typed message (SceneUpdate, FrameTransforms, ...) as the dict a client
    decodes it to: encoded and decoded again through its own protobuf schema."""
    schema = message.get_schema()
    decode = _decoder({'encoding': schema.encoding, 'schemaName': schema.name,
                       'schema': base64.b64encode(schema.data).decode(), 'topic': schema.name})
    decoded: dict[str, Any] = decode(message.encode())
    return decoded
