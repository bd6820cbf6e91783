"""analyze_bag on a REAL recorded cell run tiled to 1 000 000 and 4 000 000 messages, against
a rosbags read + deserialise of the analysed topics of the same bag, measured in the same run
(figures vary ±20-50 % on the shared 2-core VMs; see platform.md).

benchmarks/analysis.py measures a synthetic run; a recorded one has more topics, more
/diagnostics (decoded message by message) and real timing, which the synthetic bag hides
(issue 24). The source bag, in this order of preference (printed):
1. ``--bag PATH``;
2. the newest ``runs/*/bag`` of this checkout (what ``make run`` records);
3. one recorded here by running the cell (``run_cell``, as ``make run`` does, with the shipped
   program cut to one cycle and a 12-pose calibration: ~2 min), into a temporary folder.
The source is only read. It is tiled (:func:`positioning_cell.testing.tiled_bag.tile_bag`:
copies end to end, log times, header stamps and the markers' times shifted by the bag's span
per copy, the cell's writer) to each size asked.

Measured on each tiled bag, each in a fresh process with its peak RSS (VmHWM), the four in
turn ``--repeat`` times (default 2), the fastest run of each kept (its RSS: the largest):
- BASELINE: rosbags (``AnyReader``) reading and deserialising every message of the topics
  the analysis reads (positioning_cell.analysis.summary.READ_TOPICS: the replay's and the
  error budget's, /legs/joint_states and /legs/joint_trajectory among them, which the
  analysis decodes in its second pass);
- the same of the replay's topics only (ANALYSED_TOPICS), informative: the baseline before
  the error budget's pass was added (issue 23), printed so that both ratios can be read;
- ``analyze`` (what the ``analyze_bag`` command does after its imports: read, replay, error
  budget, report, JSON and the four plots, drawn by two forked worker processes whose peak RSS
  is printed apart: positioning_cell.analysis.plot_workers), and ``analyze --no-plots``.
Rates are messages of the bag per second.

Targets (issue 24): analyze with the plots >= 1.5x the baseline on the 1 M bag; peak RSS <=
300 MiB, growing by <= 20 % from the 1 M to the 4 M bag.

Run: ``.venv/bin/python benchmarks/analysis_recorded.py [--bag PATH] [--messages N ...]``
(make bench). Exits non-zero only if an analysis is wrong (a program visit missing, a mode
missing, a problem reported), never on speed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml
from analysis import child, peak_rss_mib, rosbags_decoded

from positioning_cell.analysis.summary import ANALYSED_TOPICS, READ_TOPICS, analyse_bag
from positioning_cell.config import config_path
from positioning_cell.testing.tiled_bag import tile_bag
from positioning_cell.tools.analyze_bag import ANALYSIS_ENVIRONMENT

ROOT = Path(__file__).resolve().parents[1]
RSS_TARGET_MIB = 300.0
RSS_GROWTH = 1.2
SPEED_TARGET = 1.5


# -- the source bag -------------------------------------------------------------------------
def newest_run_bag(root: Path) -> Path | None:
    """The bag of the newest ``runs/<stamp>/bag`` under ``root`` (None: none)."""
    bags = sorted(p for p in (root / 'runs').glob('*/bag') if (p / 'metadata.yaml').is_file())
    return bags[-1] if bags else None


def record_run(work: Path) -> Path:
    """Run the cell (run_cell, as ``make run``) through the shipped program cut short; the
    bag it recorded."""
    program = yaml.safe_load(config_path('program.yaml').read_text())
    program['program']['cycles'] = 1
    program['program']['calibration'].update(poses=12, hold_out=2, samples=5)
    short = work / 'program.yaml'
    short.write_text(yaml.safe_dump(program))
    runs = work / 'runs'
    subprocess.run([sys.executable, '-m', 'positioning_cell.tools.run_cell', '--program',
                    str(short), '--runs', str(runs)], check=False, env=dict(os.environ))
    bag = newest_run_bag(work)
    if bag is None:
        raise SystemExit(f'run_cell recorded no bag under {runs}')
    return bag


def source_bag(given: Path | None, work: Path) -> tuple[Path, str]:
    """The source bag and how it was found (module docstring)."""
    if given is not None:
        return given, '--bag'
    found = newest_run_bag(ROOT)
    if found is not None:
        return found, 'the newest runs/*/bag of this checkout'
    return record_run(work), 'recorded now by run_cell (one cycle, short calibration)'


# -- fresh processes ------------------------------------------------------------------------
#: The baselines' topics by name (module docstring).
BASELINE_TOPICS = {'read': READ_TOPICS, 'replayed': ANALYSED_TOPICS}


def baseline_child(bag: Path, which: str) -> None:
    """The rosbags baseline ``which`` (:data:`BASELINE_TOPICS`) on ``bag`` in this process;
    prints JSON: seconds, peak RSS, messages decoded."""
    start = time.perf_counter()
    count = rosbags_decoded(bag, BASELINE_TOPICS[which])
    print(json.dumps({'seconds': time.perf_counter() - start, 'rss_mib': peak_rss_mib(),
                      'decoded': count}))


def fresh(*args: str) -> dict[str, Any]:
    """This script with ``--child *args`` in a new process, in the environment the
    analyze_bag command gives its own (``ANALYSIS_ENVIRONMENT``): its JSON line."""
    flags = [a for a in args if a.startswith('--')]
    rest = [a for a in args if not a.startswith('--')]
    result = subprocess.run([sys.executable, __file__, *flags, '--child', *rest],
                            capture_output=True, text=True, check=True,
                            env={**os.environ, **ANALYSIS_ENVIRONMENT})
    doc: dict[str, Any] = json.loads(result.stdout.strip().splitlines()[-1])
    return doc


def expected(source: Path) -> dict[str, int]:
    """In-program visits per mode of one copy of the source (the reference the tiled bag's
    analysis is checked against)."""
    a = analyse_bag(source)
    return {m.mode: m.extremes.n for m in a.modes}


def best(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The fastest of ``runs``, with the largest peak RSS of them."""
    fastest = min(runs, key=lambda r: float(r['seconds']))
    return {**fastest, 'rss_mib': max(float(r['rss_mib']) for r in runs),
            'workers_rss_mib': max(float(r.get('workers_rss_mib', 0.0)) for r in runs)}


def measure(bag: Path, work: Path, messages: int, repeat: int) -> dict[str, Any]:
    """The baselines, analyze and analyze --no-plots of the bag, each in a fresh process,
    the four taken in turn ``repeat`` times (so that a busy spell of the machine does not fall
    on one of them only); the fastest of each."""
    runs: dict[str, list[dict[str, Any]]] = {'base': [], 'replayed': [], 'whole': [],
                                             'lean': []}
    for _ in range(repeat):
        runs['base'].append(fresh('baseline', str(bag), 'read'))
        runs['replayed'].append(fresh('baseline', str(bag), 'replayed'))
        runs['whole'].append(fresh('analyze', str(bag), str(work / 'out')))
        runs['lean'].append(fresh('--no-plots', 'analyze', str(bag), str(work / 'out_lean')))
    base, replayed = best(runs['base']), best(runs['replayed'])
    whole, lean = best(runs['whole']), best(runs['lean'])
    rows = [(f'BASELINE rosbags, every topic read ({base["decoded"]:,} msgs)', base),
            (f'rosbags, the replay\'s topics only ({replayed["decoded"]:,} msgs)', replayed),
            ('ours: analyze (+ report, JSON, 4 plots)', whole),
            ('ours: analyze --no-plots (+ report, JSON)', lean)]
    rate = messages / base['seconds']
    print(f'  {"":55}  bag msgs/s   seconds  peak RSS MiB  x baseline  x replay-only')
    for name, doc in rows:
        r = messages / doc['seconds']
        print(f'  {name:55}  {r:>10,.0f}  {doc["seconds"]:8.2f}  {doc["rss_mib"]:12.0f}  '
              f'{r / rate:10.2f}  {doc["seconds"] and replayed["seconds"] / doc["seconds"]:12.2f}')
    if whole['workers_rss_mib']:
        print(f'  analyze\'s plot workers: peak RSS {whole["workers_rss_mib"]:.0f} MiB each '
              '(pages shared with the analysing process counted in both)')
    return {'baseline': base, 'replayed': replayed, 'whole': whole, 'lean': lean,
            'rate': rate}


def correct(doc: dict[str, Any], per_copy: dict[str, int], copies: int) -> bool:
    """Every mode of the program there, each with at least the visits of the complete copies
    (a mode also takes the visits before the next copy's program), no problem."""
    return (list(doc['modes'])[:len(per_copy)] == list(per_copy) and not doc['problems']
            and all(doc['visits_by_mode'].get(m, 0) >= n * copies
                    for m, n in per_copy.items()))


def timed_tile(source: Path, bag: Path, messages: int) -> tuple[Any, float]:
    start = time.perf_counter()
    tiled = tile_bag(source, bag, messages)
    return tiled, time.perf_counter() - start


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--bag', type=Path, help='the recorded bag to tile (default: the '
                        'newest runs/*/bag here, else one recorded now)')
    parser.add_argument('--messages', type=int, nargs='+', default=[1_000_000, 4_000_000],
                        help='sizes of the tiled bags (default: 1 000 000 4 000 000)')
    parser.add_argument('--repeat', type=int, default=2,
                        help='runs of each measurement, the fastest kept (default 2)')
    parser.add_argument('--child', nargs='+', help=argparse.SUPPRESS)
    parser.add_argument('--no-plots', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, *rest = args.child
        if kind == 'baseline':
            baseline_child(Path(rest[0]), rest[1])
        else:
            child(Path(rest[0]), Path(rest[1]), plots=not args.no_plots)
        return 0
    work = Path(tempfile.gettempdir()) / 'positioning_cell_bench' / 'analysis_recorded'
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    source, how = source_bag(args.bag, work)
    per_copy = expected(source)
    print(f'source bag: {source} ({how}); in-program visits per copy: {per_copy}')
    ok, results = True, {}
    for messages in args.messages:
        bag = work / f'tiled_{messages}'
        tiled, took = timed_tile(source, bag, messages)
        size = sum(f.stat().st_size for f in bag.iterdir()) / 2**20
        print(f'tiled bag: {tiled.message_count:,} messages = {tiled.copies} copies of '
              f'{tiled.source_messages:,} ({tiled.period_ns * 1e-9:.0f} s apart), {size:.0f} '
              f'MiB, written in {took:.0f} s')
        results[messages] = got = measure(bag, work, messages, args.repeat)
        full = tiled.message_count // tiled.source_messages
        for key in ('whole', 'lean'):
            if not correct(got[key], per_copy, full):
                print(f'  analysis WRONG ({key}): {got[key]}')
                ok = False
        shutil.rmtree(bag)
    first = args.messages[0]
    for messages, got in results.items():
        for key, label in (('whole', 'analyze'), ('lean', 'analyze --no-plots')):
            doc = got[key]
            ratio = messages / doc['seconds'] / got['rate']
            verdict = 'met' if ratio >= SPEED_TARGET else 'NOT met'
            rss = 'met' if doc['rss_mib'] <= RSS_TARGET_MIB else 'NOT met'
            print(f'{messages:,} msgs, {label}: {ratio:.2f} x the baseline (target >= '
                  f'{SPEED_TARGET}: {verdict}{"" if key == "whole" else ", informative"}; '
                  f'{got["replayed"]["seconds"] / doc["seconds"]:.2f} x the replay\'s '
                  f'topics only), peak RSS {doc["rss_mib"]:.0f} MiB (target <= '
                  f'{RSS_TARGET_MIB:.0f}: {rss})')
        if messages != first:
            growth = got['whole']['rss_mib'] / results[first]['whole']['rss_mib']
            print(f'peak RSS of analyze, {messages:,} vs {first:,} msgs: {growth:.2f} x (target '
                  f'<= {RSS_GROWTH}: {"met" if growth <= RSS_GROWTH else "NOT met"})')
    print('analysis ' + ('correct: every program visit of every copy, every mode, no problem'
                         if ok else 'WRONG'))
    shutil.rmtree(work, ignore_errors=True)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
