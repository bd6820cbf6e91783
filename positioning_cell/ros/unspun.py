"""Nodes that no executor spins, beside a node of the cell, for the subscriptions it takes from
on demand (:class:`positioning_cell.ros.latest.Reader`,
:class:`positioning_cell.ros.senders.IdentifiedSubscription`): their subscriptions wake nobody,
and DDS keeps what came until it is taken.

Their owner does not hold them as rclpy entities, so its ``destroy_node`` leaves them. Left to
the garbage collector, they went in the collection that ``spin.run`` makes after rclpy's
shutdown, in whatever order it found them; rclpy's maintainers saw Fast DDS hang in such
collections (ros2/rclpy#456, "haphazardness of Python's garbage collector"), and one tracker
hung in that collection in CI until its 10 s stop deadline ended it (exit 1; Dec 7; not
reproduced in 24 repeats of that test and 35 stop cycles of the nodes since, ad hoc).
:func:`destroy_unspun` destroys an owner's unspun nodes
explicitly; ``spin`` calls it for each node it hosts, after the executors have stopped and
before the node itself is destroyed.
"""

from __future__ import annotations

import threading
import weakref

from rclpy.node import Node

_lock = threading.Lock()
_unspun: weakref.WeakKeyDictionary[Node, list[Node]] = weakref.WeakKeyDictionary()


def helper_node(owner: Node, suffix: str) -> Node:
    """A hidden node ``_<owner>__<suffix>`` in ``owner``'s context, without parameter services
    or /rosout: what a node of the cell keeps beside it (its unspun readers' nodes here, the
    nodes :func:`positioning_cell.ros.spin.aside_node` spins beside it). The double underscore,
    which no name of the cell's has, tells whose it is (:func:`acts_for`)."""
    return Node(f'_{owner.get_name()}__{suffix}', context=owner.context,
                start_parameter_services=False, enable_rosout=False)


def acts_for(node_name: str, owner: str) -> bool:
    """Whether the node named ``node_name`` (as the ROS graph gives it) is the node ``owner``
    or one of its :func:`helper_node` s: a subscription of either is the owner's."""
    return node_name == owner or node_name.startswith(f'_{owner}__')


def unspun_node(owner: Node, role: str, topic: str) -> Node:
    """A new :func:`helper_node` of ``owner``'s named after ``role`` and ``topic``, that no
    executor spins; destroyed with :func:`destroy_unspun` (``owner``) or :func:`destroy_one`."""
    node = helper_node(owner, f'{role}_{topic.strip("/").replace("/", "_")}')
    with _lock:
        _unspun.setdefault(owner, []).append(node)
    return node


def destroy_one(owner: Node, node: Node) -> None:
    """Destroy one of ``owner``'s unspun nodes (nothing if it was destroyed already)."""
    with _lock:
        mine = _unspun.get(owner, [])
        if node not in mine:
            return
        mine.remove(node)
    node.destroy_node()


def destroy_unspun(owner: Node) -> int:
    """Destroy every unspun node of ``owner`` (their subscriptions with them): how many."""
    with _lock:
        nodes = _unspun.pop(owner, [])
    for node in nodes:
        node.destroy_node()
    return len(nodes)
