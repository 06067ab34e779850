#!/usr/bin/env python3
"""Reference-free sharpness of a 2D trajectory: the entropy of the histogram of laser end points
over grid cells, every scan of a CARMEN log placed at the trajectory's pose (lower = crisper
walls = a more self-consistent trajectory). Used in docs/posegraph.md ("Freiburg 079").

usage: map_entropy.py LOG.clf[.gz] TRAJ.txt [TRAJ.txt ...]
  LOG: CARMEN log whose FLASER lines are the scans (the n-th FLASER line is scan n);
  TRAJ: `scan_index timestamp x y theta` (ours) or the datasets' reference files.
Prints, per trajectory and cell size (5 cm, 2.5 cm): cells hit and entropy (nats), using every
second beam with ranges in (0.05, 15) m."""
import gzip
import math
import sys

from trajfile import read_trajectory


def read_scans(path):
    opener = gzip.open if path.endswith('.gz') else open
    scans = []
    with opener(path, 'rt') as f:
        for line in f:
            if line.startswith('FLASER'):
                a = line.split()
                n = int(a[1])
                scans.append([float(v) for v in a[2:2 + n]])
    return scans


def entropy(scans, poses, res):
    cells = {}
    for i, ranges in enumerate(scans):
        if i not in poses:
            continue
        x, y, t = poses[i]
        n = len(ranges)
        # CARMEN: 180/360 beams over 180 deg, or 181/361 including both ends.
        step = math.pi / (n - 1) if n in (181, 361) else math.pi / n
        for j in range(0, n, 2):
            d = ranges[j]
            if not 0.05 < d < 15.0:
                continue
            a = t - math.pi / 2 + j * step
            k = (math.floor((x + d * math.cos(a)) / res), math.floor((y + d * math.sin(a)) / res))
            cells[k] = cells.get(k, 0) + 1
    total = sum(cells.values())
    return len(cells), -sum(c / total * math.log(c / total) for c in cells.values())


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    scans = read_scans(sys.argv[1])
    for path in sys.argv[2:]:
        poses = read_trajectory(path)
        for res in (0.05, 0.025):
            n, h = entropy(scans, poses, res)
            print('%s  cell %.3f m: %d cells, entropy %.4f' % (path, res, n, h))


if __name__ == '__main__':
    main()
