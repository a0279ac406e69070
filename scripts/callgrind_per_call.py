#!/usr/bin/env python3
"""Instructions per call of one function in a Google Benchmark case, measured with valgrind's callgrind
(repeatable, unlike wall time on a loaded machine).

Runs the benchmark binary twice under callgrind, with collection switched on only inside functions matching
`--function` (a callgrind --toggle-collect pattern, e.g. 'diekf::ImagePreprocessor::process*') and two
different --benchmark_min_time values, and reports (Ir_2 - Ir_1) / (calls_2 - calls_1): the instructions of a
steady-state call, without the one-off cost of the first calls (allocation, lazy symbol binding).

Example (from the catkin workspace):
  scripts/callgrind_per_call.py --function 'diekf::ImagePreprocessor::process*' -- \
      devel/lib/diekf/diekf_benchmark --benchmark_filter='BM_PreprocessFrame/90/58$'
"""
import argparse
import os
import re
import subprocess
import sys
import tempfile


def parse(path, pattern):
    """Returns (total Ir, calls of functions whose name matches the glob `pattern`)."""
    regex = re.compile('^' + re.escape(pattern).replace(r'\*', '.*') + '$')
    names = {}
    matching = set()
    total = None
    calls = 0
    pending_cfn = None
    with open(path) as f:
        for line in f:
            line = line.rstrip('\n')
            m = re.match(r'^(c?fn)=\((\d+)\)(?: (.*))?$', line)
            if m:
                fid, name = m.group(2), m.group(3)
                if name is not None:
                    names[fid] = name
                    if regex.match(name):
                        matching.add(fid)
                pending_cfn = fid if m.group(1) == 'cfn' else None
                continue
            if line.startswith('calls=') and pending_cfn is not None:
                if pending_cfn in matching:
                    calls += int(line.split('=')[1].split()[0])
                pending_cfn = None
                continue
            if line.startswith('summary:') or line.startswith('totals:'):
                total = int(line.split()[1])
    return total, calls


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--function', required=True, help="callgrind --toggle-collect pattern")
    ap.add_argument('--min-times', type=lambda v: [float(x) for x in v.split(',')], default=[0.02, 0.2],
                    help='two --benchmark_min_time values, s (default 0.02,0.2)')
    ap.add_argument('command', nargs=argparse.REMAINDER, help='-- program and arguments')
    args = ap.parse_args()
    cmd = args.command[1:] if args.command[:1] == ['--'] else args.command
    if not cmd:
        ap.error('no command given')
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for min_time in args.min_times:
            out = os.path.join(tmp, 'callgrind.out')
            subprocess.run(['valgrind', '--tool=callgrind', '--callgrind-out-file=' + out,
                            '--toggle-collect=' + args.function] + cmd +
                           ['--benchmark_min_time=%g' % min_time],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            results.append(parse(out, args.function))
    (ir1, n1), (ir2, n2) = results
    if not n1 or n2 <= n1:
        sys.exit('not enough calls of %s recorded: %d, %d' % (args.function, n1, n2))
    print('%-45s %12.0f Ir/call  (calls %d -> %d)' % (args.function, (ir2 - ir1) / (n2 - n1), n1, n2))


if __name__ == '__main__':
    main()
