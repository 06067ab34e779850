#!/usr/bin/env python3
"""Where along a run an ATE sits: the estimate rigidly aligned onto the reference (as the
evaluator does), then the largest position error in each of N equal parts of the matched poses
in scan order. Used in docs/rbpf.md ("More particles are no cure either"): a run whose error is
one part of the building displaced against the rest shows it in the parts that map that area;
a mis-closed loop shows metres in a few parts.

usage: ate_segments.py REF.txt PARTS EST.txt [EST.txt ...]
  Files: `scan_index timestamp x y theta` (ours and the datasets' references). Prints per
  estimate: its directory name, the ATE RMSE, and the largest error of each part (m)."""
import math
import os
import sys

from ate_spectrum import align
from trajfile import read_trajectory


def main(argv):
    if len(argv) < 4:
        sys.exit(__doc__)
    ref = read_trajectory(argv[1])
    parts = int(argv[2])
    if parts < 1:
        sys.exit("ate_segments.py: PARTS must be >= 1")
    for path in argv[3:]:
        est = read_trajectory(path)
        keys = sorted(k for k in ref if k in est)
        if len(keys) < parts:
            print(f"{path}: only {len(keys)} poses match the reference")
            continue
        r = [ref[k][:2] for k in keys]
        a = align(r, [est[k][:2] for k in keys])
        err = [math.hypot(x - u, y - v) for (x, y), (u, v) in zip(a, r)]
        rmse = math.sqrt(sum(e * e for e in err) / len(err))
        n = len(err)
        worst = [max(err[i * n // parts:(i + 1) * n // parts]) for i in range(parts)]
        name = os.path.basename(os.path.dirname(os.path.abspath(path)))
        print(f"{name:>24} {rmse:.3f} | " + " ".join(f"{w:.2f}" for w in worst))


if __name__ == "__main__":
    main(sys.argv)
