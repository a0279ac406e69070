#!/usr/bin/env python3
"""Ground textures the estimator was not developed on, for diekf_simulate --texture FILE (docs/results.md,
"Ground the estimator was not developed on").

Writes 8-bit PGM images of 2048 x 2048 px, meant for --texture-size 2.0 (1 mm per pixel), deterministic (seeded):
  planks.pgm  a wooden floor: planks 12 cm wide, each its own shade, with grain that runs along them (4 cm long, a
              pixel or two across) and dark seams: texture mostly across one direction (the aperture problem)
  carpet.pgm  a plain carpet: isotropic speckle of about 1 mm at 5 % contrast, which sinks into the sensor's noise
              from a few tens of cm up at webcam resolution
  tiles.pgm   large floor tiles (30 cm), nearly uniform but for a faint mottle, with 4 mm grout lines: sparse texture

Usage: make_textures.py [--output DIR] (default: the current directory). Needs numpy only.
"""
import argparse
import os

import numpy as np

N = 2048  # px per tile side (2 m at --texture-size 2.0)


def blur1d(a, sigma, axis):
    """Gaussian blur along one axis, periodic (the texture tiles)."""
    r = int(3 * sigma) + 1
    x = np.arange(-r, r + 1)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    k /= k.sum()
    out = np.zeros_like(a)
    for i, w in zip(x, k):
        out += w * np.roll(a, i, axis=axis)
    return out


def blur(a, sigma):
    return blur1d(blur1d(a, sigma, 0), sigma, 1)


def unit(a):
    return (a - a.mean()) / a.std()


def planks(rng):
    y = np.arange(N)[:, None]
    plank_px = 123  # 12 cm
    shade = 120 + 25 * rng.standard_normal(N // plank_px + 1)[y // plank_px]
    grain = unit(blur1d(blur1d(rng.standard_normal((N, N)), 40.0, 1), 1.5, 0))  # long along x
    img = shade + 14 * grain
    return np.where((y % plank_px) < 2, 55.0, img)


def carpet(rng):
    return 128 + 6 * unit(blur(rng.standard_normal((N, N)), 1.2))


def tiles(rng):
    y = np.arange(N)[:, None]
    x = np.arange(N)[None, :]
    tile_px = 307  # 30 cm
    shade = 150 + 8 * rng.standard_normal(64)[((y // tile_px) * 7 + x // tile_px) % 64]
    img = shade + 2.5 * unit(blur(rng.standard_normal((N, N)), 6.0))
    grout = ((y % tile_px) < 4) | ((x % tile_px) < 4)
    return np.where(grout, 90.0, img)


def save_pgm(path, img):
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    with open(path, "wb") as f:
        f.write(b"P5\n%d %d\n255\n" % (img.shape[1], img.shape[0]))
        f.write(img.tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output", default=".", help="folder for the .pgm files")
    args = ap.parse_args()
    os.makedirs(args.output, exist_ok=True)
    for seed, (name, make) in enumerate([("planks", planks), ("carpet", carpet), ("tiles", tiles)]):
        img = make(np.random.default_rng(38 + seed))
        path = os.path.join(args.output, name + ".pgm")
        save_pgm(path, img)
        print(f"{path}: mean {img.mean():.1f}, std {img.std():.1f} grey levels")


if __name__ == "__main__":
    main()
