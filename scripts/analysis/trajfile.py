"""Reader for the trajectory files the analysis scripts take: `scan_index timestamp x y theta`
per line (ours, the datasets' references, the RBPF benchmark's converted MRPT paths); lines
starting with '#' and blank lines are skipped."""


def read_trajectory(path):
    """scan_index -> (x, y, theta)"""
    poses = {}
    with open(path) as f:
        for line in f:
            if line.startswith('#') or not line.strip():
                continue
            a = line.split()
            poses[int(a[0])] = (float(a[2]), float(a[3]), float(a[4]))
    return poses
