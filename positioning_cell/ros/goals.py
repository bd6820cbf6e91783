"""One way to run an action goal's work: the work runs in a worker thread; the goal's thread
publishes the feedback the work gives (and, every ``period`` s, what ``tick`` makes), turns
a cancel (or the node's shutdown) into the work's stop event, calls ``on_stop`` once at once
(the drives stopped) and hands back how the work ended, typed (:class:`Ran`). The action
servers of the positioner's operator interface and of the calibrator run their goals so."""

from __future__ import annotations

import contextlib
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from rclpy.action import GoalResponse

T = TypeVar('T')

#: How often the goal's thread looks for a cancel and passes feedback on, s.
PERIOD_S = 0.1


@dataclass(frozen=True)
class Ran(Generic[T]):
    """How a goal's work ended: its value, or the exception it raised (``error``);
    ``stopped``: a stop was asked (a cancel or a shutdown) while it ran; ``canceled``: by the
    goal's cancel."""

    value: T | None
    error: BaseException | None
    stopped: bool
    canceled: bool


def run_goal(goal_handle: Any, work: Callable[[threading.Event, Callable[[Any], None]], T], *,
             on_stop: Callable[[], object] | None = None, tick: Callable[[], Any] | None = None,
             closing: threading.Event | None = None, period: float = PERIOD_S) -> Ran[T]:
    """Run ``work(stop, feedback)`` for ``goal_handle`` (module docstring): ``feedback(msg)``
    queues a feedback message the goal's thread publishes; ``stop`` is set on a cancel or when
    ``closing`` is set, and ``on_stop()`` is then called once; ``tick()`` (if given) is
    called before the work starts and every ``period`` s while it runs, a message it returns
    published as feedback."""
    stop = threading.Event()
    messages: queue.SimpleQueue[Any] = queue.SimpleQueue()
    box: dict[str, Any] = {}

    def target() -> None:
        try:
            box['value'] = work(stop, messages.put)
        except BaseException as err:  # handed back to the goal's thread
            box['error'] = err

    def publish(message: Any) -> None:
        if message is not None:
            goal_handle.publish_feedback(message)

    def pass_on() -> None:
        while not messages.empty():
            publish(messages.get())

    canceled = False
    worker = threading.Thread(target=target, daemon=True, name='goal-work')
    if tick is not None:
        publish(tick())
    worker.start()
    while worker.is_alive():
        worker.join(period)
        if not stop.is_set():
            canceled = bool(goal_handle.is_cancel_requested)
            if canceled or (closing is not None and closing.is_set()):
                stop.set()
                if on_stop is not None:
                    on_stop()
        pass_on()
        if tick is not None and worker.is_alive():
            publish(tick())
    pass_on()
    return Ran(box.get('value'), box.get('error'), stop.is_set(), canceled)


class OneGoal:
    """The guard of an action server that runs one goal at a time (the calibrator's, the
    coordinator's): :meth:`accept` is its goal callback (a goal while one runs, or once the
    node closes, is rejected and logged with ``what`` the server runs); :meth:`running` wraps
    the goal's execution; :meth:`close` refuses new goals and waits for the running one to
    end (its work sees ``closing``: :func:`run_goal`)."""

    def __init__(self, logger: Any, what: str) -> None:
        self._logger, self._what = logger, what
        self._lock = threading.Lock()
        self.busy = False
        self.closing = threading.Event()
        self._idle = threading.Event()
        self._idle.set()

    def accept(self, _goal: Any) -> GoalResponse:
        """ACCEPT, or REJECT while a goal runs or the node shuts down."""
        with self._lock:
            if self.busy or self.closing.is_set():
                self._logger.warning(f'{self._what} goal rejected: ' + (
                    'the node shuts down' if self.closing.is_set()
                    else f'a {self._what} is running'))
                return GoalResponse.REJECT
            self.busy = True
            self._idle.clear()
        return GoalResponse.ACCEPT

    @contextlib.contextmanager
    def running(self) -> Iterator[None]:
        """Around an accepted goal's execution: idle again when it ends, however."""
        try:
            yield
        finally:
            with self._lock:
                self.busy = False
                self._idle.set()

    def close(self, wait: float) -> None:
        """Reject every new goal; wait up to ``wait`` s for the running one to end."""
        self.closing.set()
        self._idle.wait(wait)
