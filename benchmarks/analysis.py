"""analyze_bag on bags of 1 000 000 and 4 000 000 messages against what reading them costs,
measured in the same run (figures vary ±20-50 % on the shared 2-core VMs; see platform.md).

The bags are long synthetic cell runs (positioning_cell.testing.synthetic_run, the cell's own
writer: 64 KiB chunks with CRCs): the ISO cube's five poses visited under the three
compensation modes, a move every 2.5 s, the tracker at 20 Hz with the true pose at the same
stamps, the program steps and the positioner's mode diagnostics, and /legs/joint_states filler
so that the analysed topics are the share of the messages they are in a recorded run of the
cell (~13 %: 5 100 of 43 900 in a `make run` bag).

Baselines, each reading the same 1 M-message bag:
- mcap's reader iterating every record (``make_reader(f).iter_messages()``, no decoding);
- rosbags reading and deserialising the analysed topics (``AnyReader``; what analyze_bag did);
- rosbags' raw iteration of the analysed topics plus a numpy structured-dtype decode of the
  fixed-layout pose messages (the cheapest way to the numbers with the libraries alone);
- that numpy decode alone (decoded pose messages per second).
Ours: the indexed read and vectorised decode (``IndexedBag.read``); ``analyse_bag`` (read,
replay through the monitor's rules, per mode/pose figures); and the whole of ``analyze`` (that,
the report, the JSON and the four plots: what the ``analyze_bag`` command does after its
imports), and with ``--no-plots``, each in a fresh process with that process's peak RSS
(VmHWM), on the 1 M and the 4 M bag. Rates are messages of the bag per second.

Targets (issue 15): analyze ≥ 500 k bag msgs/s and ≥ 0.5× the raw read + vectorised decode
baseline; peak RSS ≤ 300 MiB on the 1 M bag and ≤ 1.2× that on the 4 M bag. The fleet figures
are benchmarks/fleet.py's.

Run: ``.venv/bin/python benchmarks/analysis.py [--messages N] [--large M]`` (make bench). Exits
non-zero only if an analysis is wrong (a move did not settle, a mode is missing), never on
speed.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from positioning_cell.analysis.summary import ANALYSED_TOPICS, analyse_bag
from positioning_cell.names import MEASURED_POSE, TARGET, TRUE_POSE
from positioning_cell.testing.synthetic_run import long_run, write_run_bag
from positioning_cell.tools.analyze_bag import ANALYSIS_ENVIRONMENT

MODES = ['none', 'model', 'measured']


def write_bag(path: Path, messages: int) -> tuple[int, int]:
    """A synthetic run of at least ``messages`` messages at ``path``: (messages, moves)."""
    run, filler_rate = long_run(messages)
    return write_run_bag(path, run, joint_state_rate=filler_rate), int(run.target_time.size)


# -- baselines ----------------------------------------------------------------------------
def mcap_all_records(bag: Path) -> int:
    """Every message record of the bag through mcap's reader, not decoded."""
    from mcap.reader import make_reader

    count = 0
    for file in sorted(bag.glob('*.mcap')):
        with file.open('rb') as stream:
            for _ in make_reader(stream).iter_messages():
                count += 1
    return count


def rosbags_decoded(bag: Path, topics: Collection[str] = ANALYSED_TOPICS) -> int:
    """``topics`` (default: the replay's) read and deserialised by rosbags (what analyze_bag
    did)."""
    from rosbags.highlevel import AnyReader

    count = 0
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, data in reader.messages(conns):
            reader.deserialize(data, conn.msgtype)
            count += 1
    return count


#: The CDR layout of a pose message with frame_id 'base' (5 bytes with its NUL): header
#: stamp, the frame id, padding to 8, position, orientation (and the covariance).
def _pose_dtype(covariance: bool) -> np.dtype[Any]:
    fields: list[tuple[str, Any]] = [
        ('encapsulation', 'V4'), ('sec', '<i4'), ('nanosec', '<u4'), ('frame_len', '<u4'),
        ('frame', 'S5'), ('pad', 'V7'), ('position', '<f8', (3,)),
        ('orientation', '<f8', (4,))]
    if covariance:
        fields.append(('covariance', '<f8', (36,)))
    return np.dtype(fields)


def numpy_decode(payloads: dict[str, list[bytes]]) -> int:
    """The pose topics' payloads decoded with a numpy structured dtype (all the same length:
    the frame id is 'base'); returns how many."""
    count = 0
    for topic, covariance in ((TARGET, False), (MEASURED_POSE, True), (TRUE_POSE, False)):
        raw = payloads.get(topic, [])
        dtype = _pose_dtype(covariance)
        assert all(len(r) == dtype.itemsize for r in raw), topic
        arr = np.frombuffer(b''.join(raw), dtype=dtype)
        stamp = arr['sec'] + arr['nanosec'] * 1e-9
        assert np.isfinite(stamp).all() and np.isfinite(arr['position']).all()
        count += arr.shape[0]
    return count


def rosbags_raw(bag: Path) -> dict[str, list[bytes]]:
    """The analysed topics' payloads through rosbags' raw iteration (no deserialisation)."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list[bytes]] = {}
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic in ANALYSED_TOPICS]
        for conn, _, data in reader.messages(conns):
            out.setdefault(conn.topic, []).append(bytes(data))
    return out


def timed(what: Any, *args: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    value = what(*args)
    return value, time.perf_counter() - start


# -- the whole command's work, in a fresh process ------------------------------------------
def peak_rss_mib() -> float:
    """This process's peak resident set (VmHWM, MiB): of its own image only (ru_maxrss would
    start from the forking parent's)."""
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith('VmHWM:'):
            return int(line.split()[1]) / 1024
    return float('nan')


def child(bag: Path, out: Path, plots: bool) -> None:
    """``analyze`` of ``bag`` into ``out`` in this process (its imports done first); prints
    JSON: the time of the call, the process's peak RSS, what was found."""
    from positioning_cell.tools.analyze_bag import analyze

    start = time.perf_counter()
    output = analyze(bag, out, plots=plots)
    seconds = time.perf_counter() - start
    a = output.analysis
    workers = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # plot workers
    print(json.dumps({'seconds': seconds, 'rss_mib': peak_rss_mib(), 'workers_rss_mib': workers,
                      'visits': len(a.replay.visits), 'modes': [m.mode for m in a.modes],
                      'visits_by_mode': {m.mode: m.extremes.n for m in a.modes},
                      'measured': a.replay.measured.count, 'truth': a.replay.truth.count,
                      'problems': list(a.problems), 'plots': len(output.plots)}))


def in_fresh_process(bag: Path, out: Path, plots: bool = True) -> dict[str, Any]:
    command = [sys.executable, __file__, '--child', str(bag), str(out)]
    result = subprocess.run(command + ([] if plots else ['--no-plots']), capture_output=True,
                            text=True, check=True,  # the analyze_bag command's environment
                            env={**os.environ, **ANALYSIS_ENVIRONMENT})
    doc: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    return doc


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--messages', type=int, default=1_000_000,
                        help='messages in the bag (at least this many; default 1 000 000)')
    parser.add_argument('--large', type=int, default=4_000_000,
                        help='messages in the large bag for the RSS check (0: none)')
    parser.add_argument('--child', nargs=2, type=Path, help=argparse.SUPPRESS)
    parser.add_argument('--no-plots', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child, plots=not args.no_plots)
        return 0
    work = Path(tempfile.gettempdir()) / 'positioning_cell_bench' / 'analysis'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    bag = work / 'bag'
    (written, moves), took = timed(write_bag, bag, args.messages)
    size = sum(f.stat().st_size for f in bag.iterdir()) / 2**20
    print(f'bag: {written:,} messages ({moves} moves), {size:.0f} MiB, written in {took:.0f} s')

    rows: list[tuple[str, float, str]] = []
    n, s = timed(mcap_all_records, bag)
    rows.append(('mcap reader, every record (no decoding)', written / s, f'{n:,} records'))
    n, s = timed(rosbags_decoded, bag)
    rows.append(('rosbags, analysed topics read + deserialised', written / s,
                 f'{n:,} decoded'))
    payloads, s_raw = timed(rosbags_raw, bag)
    n, s_np = timed(numpy_decode, payloads)
    rows.append(('rosbags raw read of the analysed topics', written / s_raw, ''))
    rows.append(('numpy structured decode of the pose messages', n / s_np,
                 f'{n:,} decoded (decoded msgs/s)'))
    baseline = written / (s_raw + s_np)
    rows.append(('BASELINE raw read + vectorised decode', baseline, ''))
    del payloads

    from positioning_cell.bag.indexed import IndexedBag

    def indexed_read() -> int:
        with IndexedBag(bag) as reader:
            read = reader.read(ANALYSED_TOPICS)
        return sum(d.count for d in read.topics.values())

    n, s = timed(indexed_read)
    rows.append(('ours: indexed read + vectorised decode', written / s, f'{n:,} decoded'))
    analysis, s = timed(analyse_bag, bag)
    rows.append(('ours: analyse_bag (read, replay, figures)', written / s,
                 f'{analysis.replay.measured.count + analysis.replay.truth.count:,} poses '
                 'through the monitor'))
    lean = in_fresh_process(bag, work / 'out_lean', plots=False)
    rows.append(('ours: analyze --no-plots (+ report, JSON)', written / lean['seconds'],
                 f'{lean["seconds"]:.2f} s, fresh process, peak RSS {lean["rss_mib"]:.0f} MiB'))
    whole = in_fresh_process(bag, work / 'out')
    rate = written / whole['seconds']
    rows.append(('ours: analyze (+ report, JSON, 4 plots)', rate,
                 f'{whole["seconds"]:.2f} s, fresh process, peak RSS '
                 f'{whole["rss_mib"]:.0f} MiB'))
    width = max(len(r[0]) for r in rows)
    print(f'{"":{width}}  bag msgs/s')
    for name, value, note in rows:
        print(f'{name:{width}}  {value:>12,.0f}  {note}')
    for label, doc in (('analyze', whole), ('analyze --no-plots', lean)):
        r = written / doc['seconds']
        print(f'{label}: {r / 1e3:,.0f} k bag msgs/s (target >= 500 k), {r / baseline:.2f} x '
              'the raw read + vectorised decode baseline (target >= 0.5), peak RSS '
              f'{doc["rss_mib"]:.0f} MiB (target <= 300)')
    ok = all(d['visits'] == moves and d['modes'] == MODES and not d['problems']
             for d in (whole, lean))
    if args.large:
        shutil.rmtree(bag)
        large = work / 'large'
        (big, big_moves), took = timed(write_bag, large, args.large)
        print(f'large bag: {big:,} messages ({big_moves} moves), written in {took:.0f} s')
        four = in_fresh_process(large, work / 'out_large')
        print(f'analyze of the large bag: {four["seconds"]:.2f} s = '
              f'{big / four["seconds"]:,.0f} bag msgs/s, peak RSS {four["rss_mib"]:.0f} MiB = '
              f'{four["rss_mib"] / whole["rss_mib"]:.2f} x the 1 M bag\'s (target <= 1.2)')
        ok = ok and four['visits'] == big_moves and four['modes'] == MODES
    print('analysis ' + ('correct: every move settled, three modes, no problem' if ok else
                         f'WRONG: {whole}'))
    shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
