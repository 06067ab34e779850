#!/usr/bin/env python3
"""Scan-to-scan jitter of a trajectory: RMS of the second differences of position and heading
between consecutive poses, and the median time step. For a smoothly driven robot the second
difference is acceleration x dt^2; independent per-pose noise of sigma adds sigma * sqrt(6).
Used in docs/posegraph.md ("Freiburg 079").

usage: trajectory_jitter.py TRAJ.txt [TRAJ.txt ...]   (`scan_index timestamp x y theta`)"""
import math
import sys


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        p = []
        with open(path) as f:
            for line in f:
                if line.startswith('#') or not line.strip():
                    continue
                a = line.split()
                p.append(tuple(float(v) for v in a[1:5]))
        d2, t2, dt = [], [], []
        for i in range(1, len(p) - 1):
            d2.append(math.hypot(p[i - 1][1] - 2 * p[i][1] + p[i + 1][1],
                                 p[i - 1][2] - 2 * p[i][2] + p[i + 1][2]))
            t2.append(wrap(p[i + 1][3] - p[i][3]) - wrap(p[i][3] - p[i - 1][3]))
            dt.append(p[i + 1][0] - p[i][0])
        rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))
        dt.sort()
        print('%s: second differences %.4f m, %.4f rad RMS; median step %.3f s' %
              (path, rms(d2), rms(t2), dt[len(dt) // 2]))


if __name__ == '__main__':
    main()
