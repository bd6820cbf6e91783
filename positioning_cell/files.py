"""Reading a file the cell is given by a parameter or a command-line option (calibration,
coordinate systems, ROS 2 parameter files with the programs, axis tests and tolerance specs,
tolerance mechanisms): one reader that cannot hang, exhaust or flood its caller.

Checked before it is read: the path is opened without blocking (``O_NONBLOCK``: a named pipe
with no writer does not wait) and the open descriptor is checked with ``fstat`` (nothing can
swap the file between the check and the read): it must be a regular file no larger than its
kind allows (:class:`FileKind`; generous for real files). A directory, a named pipe, a device
such as ``/dev/zero`` or a socket is refused without a byte read (a ``stat`` before the open
refuses what is plainly not a file without opening it at all: opening some devices acts).

Parsed by PyYAML's safe loader (libyaml's parser where present) with a composer that bounds
what a document may build: at most :data:`MAX_ALIASES` aliases, at most
:data:`MAX_ALIAS_NODES` nodes added by them (an alias counts as every node it names, so a
"billion laughs" alias bomb is refused at the alias that crosses the bound, before anything
is built), no alias of a node inside itself (a recursive structure), nesting at most
:data:`MAX_DEPTH` deep, and no explicit tag but the plain YAML ones (``!!str``, ``!!int``,
``!!float``, ``!!bool``, ``!!null``, ``!!seq``, ``!!map``: no Python objects, no custom
types). Neither library offers an alias bound: PyYAML has none, ruamel.yaml only a depth bound
(``YAML().max_depth``) on a pure-Python parser several times slower than libyaml; hence this
composer over PyYAML's parser.

Refused with a short reason: a message names the kind, the file (its path cut to
:data:`PATH_CHARS`) and the problem; a value quoted from a file goes through :func:`excerpt`,
a text from elsewhere (a YAML error) through :func:`shorten`, and :func:`brief_errors` cuts
what a reader's own checks raise to :data:`MESSAGE_CHARS`.

:func:`within` bounds the time of a load that a caller must not wait on indefinitely (the
positioner's parameter callback): it runs in a worker thread and is given up after a bound, or
at once when the process stops (:func:`abandon_loads`, which also ends any parse under way: no
stop waits for a file).
"""

from __future__ import annotations

import contextlib
import enum
import os
import reprlib
import stat
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, TypeVar

import yaml
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.events import AliasEvent, NodeEvent
from yaml.nodes import Node
from yaml.resolver import Resolver

from positioning_cell.errors import ConfigError

T = TypeVar('T')

KIB = 1024
MIB = 1024 * KIB


@dataclass(frozen=True)
class FileKind:
    """A kind of file the cell reads: its ``name`` in messages and the largest size accepted
    (``max_bytes``, bytes)."""

    name: str
    max_bytes: int


#: ROS 2 parameter files (config/cell.yaml: 20 KB) and what is read as one: run programs, axis
#: tests, tolerance specs (each a few KB).
PARAMETER_FILE = FileKind('parameter file', 1 * MIB)
#: Tolerance-analysis mechanisms (examples/: at most 7 KB).
MECHANISM_FILE = FileKind('mechanism file', 512 * KIB)
#: calibration.yaml (about 30 to 70 KB: 43 parameters and their 43 x 43 covariance at full
#: precision, which pose_uncertainty needs; format 1's 26 parameters were 10 to 30 KB under the
#: former 256 KiB): 384 KiB keeps a real file under a fifth of the limit and the largest
#: accepted one loading within a third of the positioner's load timeout (benchmarks/files.py).
CALIBRATION_FILE = FileKind('calibration file', 384 * KIB)
#: The positioner's coordinate systems file (under 1 KB).
COORDINATE_SYSTEMS_FILE = FileKind('coordinate systems file', 64 * KIB)
#: A coordinated cell's configuration (config/three_positioners.yaml: 2 KB).
CELL_FILE = FileKind('cell file', 256 * KIB)
#: A Fast DDS XML profile named by FASTRTPS_DEFAULT_PROFILES_FILE (the shipped one: 3 KB).
FAST_DDS_PROFILE = FileKind('Fast DDS profile', 1 * MIB)

#: Most aliases (``*name``) in one document.
MAX_ALIASES = 100
#: Most nodes the aliases of one document add (each alias counted as all the nodes it names).
MAX_ALIAS_NODES = 100_000
#: Deepest nesting of sequences and mappings.
MAX_DEPTH = 50
#: Longest error message of a reader (characters), and of the parts it quotes.
MESSAGE_CHARS = 300
PATH_CHARS = 120
EXCERPT_CHARS = 60
YAML_PROBLEM_CHARS = 150

_YAML_TAG = 'tag:yaml.org,2002:'
#: Explicit tags a document may carry (and the non-specific ``!``).
PLAIN_TAGS = frozenset(_YAML_TAG + t for t in ('str', 'int', 'float', 'bool', 'null', 'seq',
                                                 'map')) | {'!'}
#: The event source: libyaml's parser, else PyYAML's own (same events, slower).
_EVENTS: Any = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)
#: Set once the process stops (:func:`abandon_loads`).
_STOPPING = threading.Event()
_OPEN_FLAGS = os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
_READ_CHUNK = 1 * MIB


class Missing(enum.Enum):
    """What :func:`load_yaml` returns for a file that does not exist when asked to."""

    FILE = 'missing'


MISSING = Missing.FILE


# -- short texts -----------------------------------------------------------------------------
def shorten(text: str, limit: int = MESSAGE_CHARS) -> str:
    """``text`` cut to at most ``limit`` characters (its end replaced by '…')."""
    return text if len(text) <= limit else text[:limit - 1] + '…'


def _excerpt_repr() -> reprlib.Repr:
    r = reprlib.Repr()
    r.maxlevel, r.maxstring, r.maxother, r.maxlong = 3, EXCERPT_CHARS, EXCERPT_CHARS, 40
    r.maxlist = r.maxtuple = r.maxdict = r.maxset = r.maxfrozenset = r.maxdeque = 6
    return r


_REPR = _excerpt_repr()


def excerpt(value: Any, limit: int = EXCERPT_CHARS) -> str:
    """A short ``repr`` of a value read from a file for a message (strings, lists and
    mappings abridged with '...'; at most about ``limit`` characters)."""
    try:
        text = _REPR.repr(value)
    except ValueError:  # an integer too long to print
        text = f'<{type(value).__name__}>'
    return shorten(text, limit)


def describe(kind: FileKind, path: str | os.PathLike[str]) -> str:
    """How messages name a file: ``calibration file '/a/b.yaml'`` (a long path cut in the
    middle)."""
    text = os.fspath(path)
    if len(text) > PATH_CHARS:
        half = (PATH_CHARS - 1) // 2
        text = text[:half] + '…' + text[-half:]
    return f'{kind.name} {text!r}'


@contextlib.contextmanager
def brief_errors(limit: int = MESSAGE_CHARS) -> Iterator[None]:
    """A ConfigError raised inside leaves with its message cut to ``limit`` characters (the
    same exception, so its type stays)."""
    try:
        yield
    except ConfigError as err:
        text = str(err)
        if len(text) > limit:
            err.args = (shorten(text, limit),)
        raise


def size_text(n: int) -> str:
    """A size for people: bytes, KiB or MiB."""
    if n < KIB:
        return f'{n} bytes'
    if n < MIB:
        return f'{n / KIB:.0f} KiB'
    return f'{n / MIB:.1f} MiB'


# -- reading ---------------------------------------------------------------------------------
def _not_a_file(mode: int) -> str | None:
    """What a non-regular file is (None: a regular file)."""
    for test, what in ((stat.S_ISREG, None), (stat.S_ISDIR, 'a directory'),
                       (stat.S_ISFIFO, 'a named pipe'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket')):
        if test(mode):
            return what
    return 'not a file'


def _check(info: os.stat_result, kind: FileKind, where: str,
           error: type[ConfigError]) -> None:
    what = _not_a_file(info.st_mode)
    if what is not None:
        raise error(f'{where}: cannot be read ({what}, not a regular file)')
    if info.st_size > kind.max_bytes:
        raise error(f'{where}: too large ({size_text(info.st_size)}; a {kind.name} may have '
                    f'at most {size_text(kind.max_bytes)})')


def read_bytes(path: str | os.PathLike[str], kind: FileKind,
               error: type[ConfigError] = ConfigError, *,
               missing_ok: bool = False) -> bytes | Missing:
    """The content of the regular file ``path``, at most ``kind.max_bytes`` (module docstring);
    :data:`MISSING` if it does not exist and ``missing_ok``. ``error`` (a ConfigError type)
    names the kind, the file and the problem otherwise: missing, unreadable, not a regular file
    (a directory, a named pipe, a device: refused without blocking), too large."""
    where = describe(kind, path)
    try:
        # Plainly not a file: refused unopened. The fstat below is what counts.
        _check(os.stat(path), kind, where, error)
        fd = os.open(path, _OPEN_FLAGS)
    except ConfigError:
        raise
    except FileNotFoundError:
        if missing_ok:
            return MISSING
        raise error(f'{where}: cannot be read (No such file or directory)') from None
    except OSError as err:
        raise error(f'{where}: cannot be read ({err.strerror or err})') from None
    except ValueError as err:  # a NUL in the path
        raise error(f'{where}: cannot be read ({err})') from None
    try:
        _check(os.fstat(fd), kind, where, error)
        chunks: list[bytes] = []
        total = 0
        while chunk := os.read(fd, min(_READ_CHUNK, kind.max_bytes + 1 - total)):
            chunks.append(chunk)
            total += len(chunk)
            if total > kind.max_bytes:  # it grew while read
                raise error(f'{where}: too large (more than {size_text(kind.max_bytes)}, the '
                            f'most a {kind.name} may have)')
    except OSError as err:
        raise error(f'{where}: cannot be read ({err.strerror or err})') from None
    finally:
        os.close(fd)
    return b''.join(chunks)


def read_text(path: str | os.PathLike[str], kind: FileKind,
              error: type[ConfigError] = ConfigError, *,
              missing_ok: bool = False) -> str | Missing:
    """:func:`read_bytes` decoded as UTF-8 (a byte-order mark allowed); ``error`` names the
    first byte that is not UTF-8."""
    data = read_bytes(path, kind, error, missing_ok=missing_ok)
    if isinstance(data, Missing):
        return data
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError as err:
        raise error(f'{describe(kind, path)}: not UTF-8 text (byte 0x{data[err.start]:02x} at '
                    f'offset {err.start})') from None


# -- parsing ---------------------------------------------------------------------------------
class RefusedYAMLError(yaml.MarkedYAMLError):
    """Valid YAML that the bounded loader does not build (module docstring)."""


class _StoppingError(Exception):
    """The process stops: a parse under way is given up (:func:`abandon_loads`)."""


class BoundedSafeLoader(Composer, SafeConstructor, Resolver):
    """PyYAML's safe loader with the composer bounded (module docstring): the events come from
    libyaml's parser (PyYAML's where it is missing), the nodes from PyYAML's composer with
    counts, the values from its SafeConstructor."""

    def __init__(self, text: str) -> None:
        self._events = _EVENTS(text)
        Composer.__init__(self)
        SafeConstructor.__init__(self)
        Resolver.__init__(self)
        self._aliases = 0
        self._alias_nodes = 0
        self._nodes = 0  # every node so far, an alias counted as the nodes it names
        self._depth = 0
        self._weights: dict[int, int] = {}  # id of an anchored node -> the nodes it names

    # The event source of the composer.
    def check_event(self, *choices: Any) -> bool:
        return bool(self._events.check_event(*choices))

    def peek_event(self) -> Any:
        return self._events.peek_event()

    def get_event(self) -> Any:
        return self._events.get_event()

    def dispose(self) -> None:
        self._events.dispose()

    def construct_object(self, node: Node, deep: bool = False) -> Any:
        if _STOPPING.is_set():
            raise _StoppingError
        return super().construct_object(node, deep)

    def compose_node(self, parent: Node | None, index: Any) -> Node:
        if _STOPPING.is_set():
            raise _StoppingError
        event: Any = self.peek_event()
        if isinstance(event, AliasEvent):
            node: Any = super().compose_node(parent, index)  # ComposerError: undefined
            self._aliases += 1
            if self._aliases > MAX_ALIASES:
                raise _refused(f'more than {MAX_ALIASES} aliases', event)
            weight = self._weights.get(id(node))
            if weight is None:
                raise _refused(f'alias *{shorten(str(event.anchor), 40)} inside the node it '
                               'names (a recursive structure)', event)
            self._alias_nodes += weight
            if self._alias_nodes > MAX_ALIAS_NODES:
                raise _refused(f'its aliases name more than {MAX_ALIAS_NODES} nodes (an alias '
                               'bomb)', event)
            self._nodes += weight
            return node  # type: ignore[no-any-return]
        assert isinstance(event, NodeEvent)
        tag = getattr(event, 'tag', None)
        if tag is not None and tag not in PLAIN_TAGS:
            shown = '!!' + tag[len(_YAML_TAG):] if tag.startswith(_YAML_TAG) else tag
            raise _refused(f'tag {shorten(shown, 60)} (only plain YAML data: no tags but !!str, '
                           '!!int, !!float, !!bool, !!null, !!seq, !!map)', event)
        if self._depth >= MAX_DEPTH:
            raise _refused(f'nested more than {MAX_DEPTH} levels deep', event)
        start = self._nodes
        self._depth += 1
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        self._nodes += 1
        if event.anchor is not None:
            self._weights[id(node)] = self._nodes - start
        return node  # type: ignore[no-any-return]


def _refused(problem: str, event: Any) -> RefusedYAMLError:
    return RefusedYAMLError(None, None, problem, event.start_mark)


def _yaml_problem(err: yaml.YAMLError) -> str:
    """A YAML error in one short line: what and where (no snippet of the file)."""
    if isinstance(err, yaml.MarkedYAMLError):
        text = ', '.join(p for p in (err.context, err.problem) if p)
        mark = err.problem_mark or err.context_mark
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        return shorten(text, YAML_PROBLEM_CHARS) + where
    return shorten(str(err).replace('\n', ' '), YAML_PROBLEM_CHARS)


def parse_yaml(text: str, where: str, error: type[ConfigError] = ConfigError) -> Any:
    """The value of the single YAML document ``text`` (:class:`BoundedSafeLoader`); ``error``
    prefixed with ``where`` for invalid YAML or YAML the loader refuses."""
    loader = BoundedSafeLoader(text)
    try:
        return loader.get_single_data()
    except RefusedYAMLError as err:
        raise error(f'{where}: refused: {_yaml_problem(err)}') from None
    except _StoppingError:
        raise error(f'{where}: not loaded: the process is stopping') from None
    except yaml.YAMLError as err:
        raise error(f'{where}: not valid YAML ({_yaml_problem(err)})') from None
    except (ValueError, OverflowError, RecursionError) as err:  # e.g. an integer too long
        raise error(f'{where}: not valid YAML ({shorten(str(err), YAML_PROBLEM_CHARS)})'
                    ) from None
    finally:
        loader.dispose()


def load_yaml(path: str | os.PathLike[str], kind: FileKind,
              error: type[ConfigError] = ConfigError, *, missing_ok: bool = False) -> Any:
    """The YAML document of the file ``path``: :func:`read_text` (checked, bounded), then
    :func:`parse_yaml`; :data:`MISSING` for a file that does not exist when ``missing_ok``.
    Every refusal is ``error`` naming the kind, the file and the problem in a short text."""
    text = read_text(path, kind, error, missing_ok=missing_ok)
    if isinstance(text, Missing):
        return text
    return parse_yaml(text, describe(kind, path), error)


# -- time ------------------------------------------------------------------------------------
#: How often a wait in :func:`within` looks whether the process stops (s).
_POLL_S = 0.02


def abandon_loads() -> None:
    """The process stops (the nodes' spin loop calls this on SIGINT / SIGTERM): every load
    waited on in :func:`within`, now or later, is given up at once, and every YAML parse under
    way or to come stops at its next node, so that no stop waits for a file (a worker given up
    on ends on its own)."""
    _STOPPING.set()


def within(seconds: float, work: Callable[[], T], what: str,
           error: type[ConfigError] = ConfigError, *,
           cancel: threading.Event = _STOPPING) -> T:
    """``work()`` run in a worker thread and waited for at most ``seconds``: its value, or the
    exception it raised; ``error`` saying that ``what`` did not finish in time otherwise, or
    at once when ``cancel`` is set (by default: once the process stops, :func:`abandon_loads`).
    A worker given up on is left to end on its own, its result dropped."""
    if cancel.is_set():
        raise error(f'{what}: not loaded: the process is stopping')
    done = threading.Event()
    box: dict[str, Any] = {}

    def run() -> None:
        try:
            box['value'] = work()
        except BaseException as err:
            box['error'] = err
        finally:
            done.set()

    threading.Thread(target=run, name=f'load: {shorten(what, 40)}', daemon=True).start()
    deadline = time.monotonic() + seconds
    while not done.wait(min(_POLL_S, max(deadline - time.monotonic(), 0.0))):
        if cancel.is_set():
            raise error(f'{what}: not loaded: the process is stopping')
        if time.monotonic() >= deadline:
            raise error(f'{what}: not loaded within {seconds:g} s (a slow or stalled file '
                        'system?)')
    if 'error' in box:
        raise box['error']
    value: T = box['value']
    return value
