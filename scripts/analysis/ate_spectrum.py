#!/usr/bin/env python3
"""Where an ATE comes from: per-scan jitter or a slowly varying shape error, and whether two
estimates share their error. Used in docs/posegraph.md ("Freiburg 079").

usage: ate_spectrum.py REF.txt EST.txt [EST.txt ...]
  Files: `scan_index timestamp x y theta` (ours, the datasets' references, the RBPF benchmark's
  converted MRPT paths). Only scan indices present in every file are used.
Prints, per estimate: the ATE RMSE after a least-squares rigid (SE(2)) alignment onto REF, and
that error split by a centred moving average over +-w scans into a low-pass part (shape) and
a high-pass part (jitter). Per pair of estimates: their ATE against each other, and the
correlation of their error fields against REF (near 1: they share their error; a shared error
of REF itself would show up as a positive correlation between independent estimates)."""
import math
import sys

from trajfile import read_trajectory


def align(ref, est):
    """est rigidly moved onto ref (least squares, closed form in 2D)."""
    n = len(ref)
    rx = sum(p[0] for p in ref) / n
    ry = sum(p[1] for p in ref) / n
    ex = sum(p[0] for p in est) / n
    ey = sum(p[1] for p in est) / n
    dot = cross = 0.0
    for (ax, ay), (bx, by) in zip(ref, est):
        ax, ay, bx, by = ax - rx, ay - ry, bx - ex, by - ey
        dot += bx * ax + by * ay
        cross += bx * ay - by * ax
    t = math.atan2(cross, dot)
    c, s = math.cos(t), math.sin(t)
    return [(rx + c * (bx - ex) - s * (by - ey), ry + s * (bx - ex) + c * (by - ey))
            for bx, by in est]


def rms(vectors):
    return math.sqrt(sum(x * x + y * y for x, y in vectors) / len(vectors))


def moving_average(vectors, w):
    n = len(vectors)
    out = []
    for i in range(n):
        sx = sy = 0.0
        for j in range(i - w, i + w + 1):
            x, y = vectors[min(max(j, 0), n - 1)]  # edges repeated
            sx += x
            sy += y
        out.append((sx / (2 * w + 1), sy / (2 * w + 1)))
    return out


def main():
    if len(sys.argv) < 3:
        print(__doc__)
        return 2
    files = sys.argv[1:]
    trajs = [{k: v[:2] for k, v in read_trajectory(p).items()} for p in files]
    keys = sorted(set.intersection(*(set(t) for t in trajs)))
    if len(keys) < 3:
        print('fewer than 3 common scan indices')
        return 1
    ref = [trajs[0][k] for k in keys]
    ests = [[t[k] for k in keys] for t in trajs[1:]]
    errors = []
    print(f'{len(keys)} common poses; reference {files[0]}')
    for path, est in zip(files[1:], ests):
        a = align(ref, est)
        e = [(p[0] - q[0], p[1] - q[1]) for p, q in zip(a, ref)]
        errors.append(e)
        parts = []
        for w in (2, 10, 50):
            low = moving_average(e, w)
            high = [(p[0] - q[0], p[1] - q[1]) for p, q in zip(e, low)]
            parts.append(f'+-{w}: low {rms(low):.4f} high {rms(high):.4f}')
        print(f'{path}: ATE {rms(e):.4f} m; ' + '; '.join(parts))
    for i in range(len(ests)):
        for j in range(i + 1, len(ests)):
            a = align(ests[i], ests[j])
            d = [(p[0] - q[0], p[1] - q[1]) for p, q in zip(a, ests[i])]
            num = sum(p[0] * q[0] + p[1] * q[1] for p, q in zip(errors[i], errors[j]))
            den = math.sqrt(sum(p[0] ** 2 + p[1] ** 2 for p in errors[i]) *
                            sum(q[0] ** 2 + q[1] ** 2 for q in errors[j]))
            print(f'{files[i + 1]} vs {files[j + 1]}: ATE {rms(d):.4f} m, '
                  f'error correlation {num / den if den > 0 else 0.0:.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
