"""Messages taken with the identity of the node that published them.

The cell trusts a command or a reading only from the node it is bound to: the leg driver
takes trajectories from its positioner alone, the positioner encoder readings from its leg
driver and poses from its tracker. The middleware knows who sent each message (the publisher
GID in ``rmw_message_info_t``), but rclpy in Jazzy does not pass it on (its message info has
the timestamps and sequence numbers only; ``publisher_gid`` came with ros2/rclpy#1466, after
Jazzy). So this module takes the serialized message through rcl itself
(``rcl_take_serialized_message``, through ctypes, on the rcl subscription rclpy created) and
matches the GID to a node with the graph (``get_publishers_info_by_topic``: each publisher's
``endpoint_gid`` and node), which is how ``ros2 topic info -v`` names publishers.

A subscription here is created on a node of its own that no executor spins (as
:class:`positioning_cell.ros.latest.Reader` does): DDS keeps the history (the QoS depth)
until :meth:`IdentifiedSubscription.take` takes it, so the owner decides when to take, and
takes in one call everything that came.
"""

from __future__ import annotations

import ctypes
import threading
from functools import cache
from typing import Any, NamedTuple

from rclpy.node import Node
from rclpy.qos import QoSProfile

from positioning_cell.ros.unspun import destroy_one, unspun_node

GID_BYTES = 16  # RMW_GID_STORAGE_SIZE in Jazzy
#: What the graph names a publisher whose node it does not know yet (rmw_dds_common).
UNKNOWN_NODE = '_NODE_NAME_UNKNOWN_'


class _Allocator(ctypes.Structure):
    _fields_ = [('allocate', ctypes.c_void_p), ('deallocate', ctypes.c_void_p),
                ('reallocate', ctypes.c_void_p), ('zero_allocate', ctypes.c_void_p),
                ('state', ctypes.c_void_p)]


class _Bytes(ctypes.Structure):
    """rcutils_uint8_array_t (rcl_serialized_message_t)."""

    _fields_ = [('buffer', ctypes.POINTER(ctypes.c_uint8)), ('buffer_length', ctypes.c_size_t),
                ('buffer_capacity', ctypes.c_size_t), ('allocator', _Allocator)]


class _Gid(ctypes.Structure):
    _fields_ = [('implementation_identifier', ctypes.c_char_p),
                ('data', ctypes.c_uint8 * GID_BYTES)]


class _MessageInfo(ctypes.Structure):
    """rmw_message_info_t (rmw/types.h, Jazzy)."""

    _fields_ = [('source_timestamp', ctypes.c_int64), ('received_timestamp', ctypes.c_int64),
                ('publication_sequence_number', ctypes.c_uint64),
                ('reception_sequence_number', ctypes.c_uint64), ('publisher_gid', _Gid),
                ('from_intra_process', ctypes.c_bool)]


class _Rcl(NamedTuple):
    take: Any
    init: Any
    fini: Any
    allocator: Any


_RCL_RET_OK = 0


@cache
def _rcl() -> _Rcl:
    """The three C functions, from the libraries rclpy has loaded already."""
    rcl = ctypes.CDLL('librcl.so')
    rcutils = ctypes.CDLL('librcutils.so')
    take = rcl.rcl_take_serialized_message
    take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Bytes), ctypes.POINTER(_MessageInfo),
                     ctypes.c_void_p]
    take.restype = ctypes.c_int
    init = rcutils.rcutils_uint8_array_init
    init.argtypes = [ctypes.POINTER(_Bytes), ctypes.c_size_t, ctypes.POINTER(_Allocator)]
    init.restype = ctypes.c_int
    fini = rcutils.rcutils_uint8_array_fini
    fini.argtypes = [ctypes.POINTER(_Bytes)]
    fini.restype = ctypes.c_int
    allocator = rcutils.rcutils_get_default_allocator
    allocator.restype = _Allocator
    return _Rcl(take, init, fini, allocator)


def fully_qualified(namespace: str, name: str) -> str:
    """``/ns/name`` of a node (``/name`` in the root namespace)."""
    return f'{namespace.rstrip("/")}/{name}'


class Endpoint(NamedTuple):
    """A publisher as the graph lists it: its node's fully qualified name and its GID."""

    node: str
    gid: bytes


def named_publishers(node: Node, topic: str) -> list[Endpoint]:
    """The publishers on ``topic`` in ``node``'s graph whose node the graph names already (an
    endpoint discovered before its node's name, which ROS sends on a topic of its own, is
    listed under rmw's placeholder: left out)."""
    found = [Endpoint(fully_qualified(i.node_namespace, i.node_name),
                      bytes(i.endpoint_gid)[:GID_BYTES])
             for i in node.get_publishers_info_by_topic(topic)]
    return [e for e in found if UNKNOWN_NODE not in e.node]


def own_publisher_ids(node: Node, topic: str) -> frozenset[str]:
    """The GIDs (hex) of ``node``'s own publishers on ``topic``, from its own graph (where a
    publisher is listed as soon as it is created). A node restarted under the same name gets
    new ones: a peer that lists these has discovered *this* process, not its predecessor."""
    me = node.get_fully_qualified_name()
    return frozenset(e.gid.hex() for e in named_publishers(node, topic) if e.node == me)


class Taken(NamedTuple):
    """A message taken: its serialized bytes (CDR with the encapsulation header) and the
    fully qualified name of the node that published it ('' when the graph does not know the
    publisher yet, even after asking it again)."""

    data: bytes
    sender: str


class IdentifiedSubscription:
    """A subscription to ``topic`` (type ``msg_type``, QoS ``qos``) whose messages are taken
    with their sender (module docstring). Thread-safe."""

    def __init__(self, node: Node, msg_type: Any, topic: str, qos: QoSProfile) -> None:
        self._owner, self._node = node, unspun_node(node, 'identified', topic)
        self._sub = self._node.create_subscription(msg_type, topic, lambda _: None, qos)
        #: The topic as the graph lists it: resolved, remapped (a node set's, ros.node_sets).
        self.topic = self._sub.topic_name
        self._lock = threading.Lock()
        self._senders: dict[bytes, str] = {}
        lib = _rcl()
        self._buffer = _Bytes()
        allocator = lib.allocator()
        if lib.init(ctypes.byref(self._buffer), 0, ctypes.byref(allocator)) != _RCL_RET_OK:
            raise RuntimeError('rcutils_uint8_array_init failed')

    def take(self, limit: int = 1000) -> list[Taken]:
        """Every message received since the last call (at most ``limit``), oldest first."""
        lib, taken = _rcl(), list[tuple[bytes, bytes]]()
        info = _MessageInfo()
        with self._lock, self._sub.handle:
            pointer = self._sub.handle.pointer
            while len(taken) < limit:
                if lib.take(pointer, ctypes.byref(self._buffer), ctypes.byref(info),
                            None) != _RCL_RET_OK:
                    break
                data = ctypes.string_at(self._buffer.buffer, self._buffer.buffer_length)
                gid = bytes(info.publisher_gid.data)
                taken.append((data, gid))
        if any(gid not in self._senders for _, gid in taken):
            self.publishers()  # once per take: a publisher new since the last look
        return [Taken(data, self._senders.get(gid, '')) for data, gid in taken]

    def endpoints(self) -> list[Endpoint]:
        """The publishers on the topic now whose node the graph names already
        (:func:`named_publishers`)."""
        named = named_publishers(self._node, self.topic)
        self._senders.update((e.gid, e.node) for e in named)
        return named

    def publishers(self) -> list[str]:
        """The nodes publishing on the topic now (one entry per publisher whose node the graph
        names already)."""
        return [e.node for e in self.endpoints()]

    def destroy(self) -> None:
        """Release the subscription, its node and the take buffer."""
        with self._lock:
            destroy_one(self._owner, self._node)
            _rcl().fini(ctypes.byref(self._buffer))

