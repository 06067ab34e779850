#!/usr/bin/env python3
"""How a CARMEN log's odometry errs against a reference, step by step: for each consecutive pair
of FLASER scans, the odometry's relative motion minus the reference's (both in the earlier
pose's frame). Per axis it removes the systematic part by least squares (x and y: a scale of the
forward motion; heading: a scale of the turn plus a drift per metre), then fits the residual's
variance as  c0 + c1 * L^2 + c2 * T^2  (L: the step's translation, T: its turn) and prints
sqrt(|c|) with c's sign. c1, c2 > 0 and c0 ~ 0: the error's standard deviation is proportional
to the step (the same path in fewer, longer steps accumulates more variance). Also the RMS over
steps where the base stood still. Used in docs/posegraph.md ("How the noisy logs' odometry errs").

usage: odometry_noise.py LOG.clf[.gz] REFERENCE.txt   (reference: `scan_index timestamp x y theta`)"""
import gzip
import math
import sys

from trajfile import read_trajectory


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def between(a, b):
    dx, dy = b[0] - a[0], b[1] - a[1]
    c, s = math.cos(a[2]), math.sin(a[2])
    return (c * dx + s * dy, -s * dx + c * dy, wrap(b[2] - a[2]))


def solve(rows, ys):
    """Least squares by the normal equations (a few unknowns, no numpy needed)."""
    k = len(rows[0])
    a = [[sum(r[i] * r[j] for r in rows) for j in range(k)] for i in range(k)]
    b = [sum(r[i] * y for r, y in zip(rows, ys)) for i in range(k)]
    for i in range(k):
        for j in range(i + 1, k):
            f = a[j][i] / a[i][i]
            a[j] = [u - f * v for u, v in zip(a[j], a[i])]
            b[j] -= f * b[i]
    x = [0.0] * k
    for i in reversed(range(k)):
        x[i] = (b[i] - sum(a[i][m] * x[m] for m in range(i + 1, k))) / a[i][i]
    return x


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    opener = gzip.open if sys.argv[1].endswith('.gz') else open
    odom = []
    with opener(sys.argv[1], 'rt') as f:
        for line in f:
            t = line.split()
            if t and t[0] == 'FLASER':
                n = int(t[1])
                odom.append(tuple(float(v) for v in t[n + 2:n + 5]))
    ref = read_trajectory(sys.argv[2])
    # Steps between consecutive scans that both have a reference pose.
    pairs = [i for i in range(len(odom) - 1) if i in ref and i + 1 in ref]
    if len(pairs) < 10:
        sys.exit('too few scans with a reference pose (%d steps)' % len(pairs))
    zo = [between(odom[i], odom[i + 1]) for i in pairs]
    zr = [between(ref[i], ref[i + 1]) for i in pairs]
    length = [math.hypot(z[0], z[1]) for z in zr]
    turn = [abs(z[2]) for z in zr]
    print('%d steps, mean %.3f m and %.3f rad per step' %
          (len(pairs), sum(length) / len(length), sum(turn) / len(turn)))
    for axis, name, cols in ((0, 'x', [0]), (1, 'y', [0]), (2, 'theta', [2, 0])):
        err = [wrap(o[axis] - r[axis]) if axis == 2 else o[axis] - r[axis] for o, r in zip(zo, zr)]
        rows = [[r[c] for c in cols] for r in zr]
        sys_fit = solve(rows, err)
        res = [e - sum(s * v for s, v in zip(sys_fit, row)) for e, row in zip(err, rows)]
        var = solve([[1.0, l * l, t * t] for l, t in zip(length, turn)], [r * r for r in res])
        still = [r for r, l in zip(res, length) if l < 0.005]
        print('  %-5s systematic %s  residual RMS %.5f  standing still %s  '
              'sd: const %+.5f, per m of step %+.5f, per rad of step %+.5f' %
              (name, ' '.join('%+.4f' % v for v in sys_fit),
               math.sqrt(sum(r * r for r in res) / len(res)),
               ('%.5f (%d)' % (math.sqrt(sum(r * r for r in still) / len(still)), len(still)))
               if still else '-', *(math.copysign(math.sqrt(abs(v)), v) for v in var)))


if __name__ == '__main__':
    main()
