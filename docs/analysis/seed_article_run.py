"""The seed article's own 12 s run, its exact random draws, as vlsync replay CSVs.

Issue 2 asks for at most 4 ms on "the seed's 12 s run". `vlsyncd bench` scores the
`seed` family: the article's generator re-implemented in Rust (`vlsync-sim --family
seed`), drawn from other seeds. This script writes the run the article itself prints
(its `main`: 30 Hz camera, 10 Hz LiDAR, offset 0.18 s + 0.012 s/s on the camera clock,
noise 0.06, numpy `default_rng(3)`), so the same data can be replayed:

  python3 docs/analysis/seed_article_run.py daemon/tests/data/seed_article
  vlsyncd replay --cam daemon/tests/data/seed_article/cam.csv \
      --lidar daemon/tests/data/seed_article/lidar.csv --out /tmp/est.csv

The committed files in `daemon/tests/data/seed_article/` are this script's output; the
test `daemon/tests/seed_article.rs` replays them and scores the estimates against
`truth.csv`. Needs numpy (pip install numpy; the draws are numpy's PCG64 generator,
the same in every numpy since 1.17). Not part of the test suite.

The article's signal: a 0.9 Hz sine (0.6) plus three Gaussian bursts (at 2.2, 6.7 and
8.6 s), each stream smoothed by a Gaussian of one sample's sigma (numpy's "same"
convolution, edges included), then white noise. The camera sample stamped t_C shows
the signal at t_C + 0.18 + 0.012 t_C; the LiDAR's stamp is the signal's own time. So
for one event offset = t_L - t_C = 0.18 + 0.012 t_C, i.e. on the LiDAR clock
offset(t_L) = t_L - (t_L - 0.18) / 1.012, which truth.csv tabulates every 10 ms.
"""
import sys
from pathlib import Path

import numpy as np

CAM_HZ, LIDAR_HZ, DURATION_S = 30.0, 10.0, 12.0
OFFSET_S, DRIFT, NOISE, SEED = 0.18, 0.012, 0.06, 3


def motion(t):
    """The article's noiseless signature at true time t."""
    bursts = [(2.2, 0.25, 1.4), (6.7, 0.35, 1.0), (8.6, 0.18, 1.2)]
    out = 0.6 * np.sin(2 * np.pi * 0.9 * t)
    for centre, width, height in bursts:
        out = out + height * np.exp(-(((t - centre) / width) ** 2))
    return out


def smoothed(x, sigma=1.0):
    """Gaussian smoothing over +-3 sigma samples, output as long as the input."""
    half = int(3 * sigma)
    taps = np.exp(-(np.arange(-half, half + 1) ** 2) / (2 * sigma**2))
    return np.convolve(x, taps / taps.sum(), mode="same")


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: seed_article_run.py OUT_DIR")
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    t_cam = np.arange(0, DURATION_S, 1 / CAM_HZ)
    t_lidar = np.arange(0, DURATION_S, 1 / LIDAR_HZ)
    # the draws in the article's order: the camera's noise first, then the LiDAR's
    cam = smoothed(motion(t_cam + OFFSET_S + DRIFT * t_cam)) + rng.normal(0, NOISE, t_cam.shape)
    lidar = smoothed(motion(t_lidar)) + rng.normal(0, NOISE, t_lidar.shape)
    t_l = np.arange(0, DURATION_S, 0.01)
    truth = t_l - (t_l - OFFSET_S) / (1 + DRIFT)
    for name, t, v, head in [
        ("cam.csv", t_cam, cam, "t,value"),
        ("lidar.csv", t_lidar, lidar, "t,value"),
        ("truth.csv", t_l, truth, "t,offset"),
    ]:
        np.savetxt(out / name, np.c_[t, v], delimiter=",", header=head, comments="", fmt="%.9f")
        print(f"wrote {out / name}: {len(t)} rows")


if __name__ == "__main__":
    main()
