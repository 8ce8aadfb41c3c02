#!/usr/bin/env python3
"""CPU reference rasteriser for `activemap bench splat`, written in JAX (CPU wheel).

Same model as crates/splat (SPEC section 3): EWA projection with the 0.3 low-pass, near-plane
culling, 16x16 tiles, per-tile depth sort (numpy), front-to-back compositing with
alpha = min(0.99, o*exp(-sigma)), alpha < 1/255 skipped, transmittance < 1e-4 masked, and
each Gaussian limited to its 3-sigma / alpha-cutoff pixel box. Each tile is composited as a
dense (256 pixels x K Gaussians) array (K = longest tile list, padded), tiles mapped with
lax.map; gradients of all 14 parameters come from jax.value_and_grad.

Usage: reference.py --ply scene.ply --size 800 --repeats 3 --threads 2
Prints `ref forward median_ms <x>`, `ref forward_backward median_ms <x>`, `ref image_sum <s>`.
The first run installs jax into a venv under ~/.cache/activemap-splat-ref and re-executes.
"""
import argparse
import os
import subprocess
import sys
import time

VENV = os.path.join(os.path.expanduser("~"), ".cache", "activemap-splat-ref", "venv")


def ensure_jax():
    """Re-executes inside the venv holding jax, creating it with pip when missing."""
    try:
        import jax  # noqa: F401
        return
    except ImportError:
        pass
    python = os.path.join(VENV, "bin", "python")
    if os.path.abspath(sys.executable) == os.path.abspath(python):
        sys.exit("jax is missing from the reference venv " + VENV)
    if not os.path.exists(python):
        subprocess.check_call([sys.executable, "-m", "venv", VENV], stdout=sys.stderr)
    try:
        subprocess.check_call([python, "-c", "import jax"], stdout=sys.stderr, stderr=sys.stderr)
    except subprocess.CalledProcessError:
        subprocess.check_call([python, "-m", "pip", "install", "-q", "jax", "numpy"], stdout=sys.stderr)
    os.execv(python, [python] + sys.argv)


def read_ply(path):
    """Reads the 3DGS PLY written by crates/splat (binary little endian, float properties)."""
    import numpy as np
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    names, count = [], None
    for line in data[:end].decode().splitlines():
        w = line.split()
        if w[:2] == ["element", "vertex"]:
            count = int(w[2])
        elif w[:1] == ["property"]:
            if w[1] != "float":
                raise ValueError(f"{path}: property {w[2]} is {w[1]}, expected float")
            names.append(w[2])
    arr = np.frombuffer(data[end:end + 4 * len(names) * count], dtype="<f4").reshape(count, len(names))
    col = {n: arr[:, i] for i, n in enumerate(names)}
    stack = lambda keys: np.stack([col[k] for k in keys], axis=1).astype(np.float32)
    return {
        "means": stack(["x", "y", "z"]),
        "sh_dc": stack(["f_dc_0", "f_dc_1", "f_dc_2"]),
        "logit": col["opacity"].astype(np.float32),
        "log_scales": stack(["scale_0", "scale_1", "scale_2"]),
        "quats": stack(["rot_0", "rot_1", "rot_2", "rot_3"]),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ply", required=True)
    ap.add_argument("--size", type=int, required=True)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    # Same thread count as the Rust side: pin the process (XLA's pool follows the CPU set).
    cpus = sorted(os.sched_getaffinity(0))[: max(1, args.threads)]
    os.sched_setaffinity(0, cpus)
    ensure_jax()
    import numpy as np
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_platforms", "cpu")
    W = H = args.size
    TILE = 16
    # Camera of crates/splat bench: 90 degree FOV, identity pose, integer pixel centres.
    fx = fy = 0.5 * W / np.tan(np.pi / 4)
    cx, cy = 0.5 * W - 0.5, 0.5 * H - 0.5
    near = 0.01
    C0 = 0.28209479177387814
    lim_x = ((-0.5 - cx) / fx - 0.3 * 0.5 * W / fx, (W - 0.5 - cx) / fx + 0.3 * 0.5 * W / fx)
    lim_y = ((-0.5 - cy) / fy - 0.3 * 0.5 * H / fy, (H - 0.5 - cy) / fy + 0.3 * 0.5 * H / fy)
    g = read_ply(args.ply)
    params = {k: jnp.asarray(v) for k, v in g.items()}
    tiles_x, tiles_y = (W + TILE - 1) // TILE, (H + TILE - 1) // TILE

    def project(p):
        m = p["means"]
        x, y, z = m[:, 0], m[:, 1], m[:, 2]
        q = p["quats"] / jnp.linalg.norm(p["quats"], axis=1, keepdims=True)
        w, qx, qy, qz = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        R = jnp.stack([
            jnp.stack([1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)], -1),
            jnp.stack([2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx)], -1),
            jnp.stack([2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)], -1),
        ], -2)
        M = R * jnp.exp(p["log_scales"])[:, None, :]
        S = M @ jnp.swapaxes(M, 1, 2)
        zs = jnp.maximum(z, near)
        tx = jnp.clip(x / zs, *lim_x) * zs
        ty = jnp.clip(y / zs, *lim_y) * zs
        zero = jnp.zeros_like(zs)
        J = jnp.stack([jnp.stack([fx / zs, zero, -fx * tx / zs**2], -1),
                       jnp.stack([zero, fy / zs, -fy * ty / zs**2], -1)], -2)
        cov = J @ S @ jnp.swapaxes(J, 1, 2) + 0.3 * jnp.eye(2)
        a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
        det = a * c - b * b
        conic = jnp.stack([c / det, -b / det, a / det], -1)
        mean2d = jnp.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
        opacity = jax.nn.sigmoid(p["logit"])
        colour = 0.5 + C0 * p["sh_dc"]
        return mean2d, conic, z, opacity, colour, a, c, det

    project_jit = jax.jit(project)

    def bin_tiles(p):
        """numpy: visibility, pixel boxes, tile lists sorted by depth (padded with -1)."""
        mean2d, _, z, opacity, _, a, c, det = [np.asarray(v) for v in project_jit(p)]
        with np.errstate(divide="ignore", invalid="ignore"):
            extent = np.minimum(3.0, np.sqrt(np.maximum(2.0 * np.log(255.0 * opacity), 0.0)))
        hx, hy = np.sqrt(a) * extent, np.sqrt(c) * extent
        x0 = np.maximum(np.ceil(mean2d[:, 0] - hx), 0)
        x1 = np.minimum(np.floor(mean2d[:, 0] + hx), W - 1)
        y0 = np.maximum(np.ceil(mean2d[:, 1] - hy), 0)
        y1 = np.minimum(np.floor(mean2d[:, 1] + hy), H - 1)
        vis = (z > near) & (det > 0) & (opacity >= 1 / 255) & (x0 <= x1) & (y0 <= y1)
        idx = np.nonzero(vis)[0]
        tx0, tx1 = (x0[idx] // TILE).astype(int), (x1[idx] // TILE).astype(int)
        ty0, ty1 = (y0[idx] // TILE).astype(int), (y1[idx] // TILE).astype(int)
        nx, ny = tx1 - tx0 + 1, ty1 - ty0 + 1
        counts = nx * ny
        gid = np.repeat(idx, counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        tile = (np.repeat(ty0, counts) + local // np.repeat(nx, counts)) * tiles_x + np.repeat(tx0, counts) + local % np.repeat(nx, counts)
        order = np.lexsort((gid, z[gid], tile))
        tile, gid = tile[order], gid[order]
        per_tile = np.bincount(tile, minlength=tiles_x * tiles_y)
        K = max(int(per_tile.max()), 1)
        pos = np.arange(len(tile)) - np.repeat(np.cumsum(per_tile) - per_tile, per_tile)
        lists = -np.ones((tiles_x * tiles_y, K), dtype=np.int32)
        lists[tile, pos] = gid
        boxes = np.stack([x0, x1, y0, y1], -1).astype(np.float32)
        print(f"reference: {len(idx)} visible, {len(tile)} tile pairs, longest tile list {K}", file=sys.stderr)
        return jnp.asarray(lists), jnp.asarray(boxes)

    ty_idx, tx_idx = np.divmod(np.arange(tiles_x * tiles_y), tiles_x)
    origins = jnp.asarray(np.stack([tx_idx * TILE, ty_idx * TILE], -1).astype(np.float32))
    py, px = np.divmod(np.arange(TILE * TILE), TILE)
    local_px = jnp.asarray(np.stack([px, py], -1).astype(np.float32))

    def rasterise(p, lists, boxes):
        mean2d, conic, z, opacity, colour, *_ = project(p)

        def tile_fn(args):
            ids, origin = args
            valid = ids >= 0
            i = jnp.where(valid, ids, 0)
            pix = origin[None, :] + local_px  # (256, 2)
            d = mean2d[i][None, :, :] - pix[:, None, :]  # (256, K, 2)
            cn = conic[i]
            sigma = 0.5 * (cn[None, :, 0] * d[..., 0] ** 2 + cn[None, :, 2] * d[..., 1] ** 2) + cn[None, :, 1] * d[..., 0] * d[..., 1]
            b = boxes[i]
            inside = (pix[:, None, 0] >= b[None, :, 0]) & (pix[:, None, 0] <= b[None, :, 1]) & (pix[:, None, 1] >= b[None, :, 2]) & (pix[:, None, 1] <= b[None, :, 3])
            alpha = jnp.minimum(0.99, opacity[i][None, :] * jnp.exp(-sigma))
            alpha = jnp.where(valid[None, :] & inside & (sigma >= 0) & (alpha >= 1 / 255), alpha, 0.0)
            t_after = jnp.cumprod(1 - alpha, axis=1)
            alive = t_after >= 1e-4  # compositing stops before T drops below 1e-4
            alive = jnp.cumprod(alive, axis=1).astype(alpha.dtype)
            alpha = alpha * alive
            t_before = jnp.concatenate([jnp.ones_like(alpha[:, :1]), jnp.cumprod(1 - alpha, axis=1)[:, :-1]], axis=1)
            wgt = alpha * t_before
            rgb = wgt @ colour[i]
            depth = wgt @ z[i]
            return rgb, depth

        # Recompute each tile in the backward pass instead of storing its (256 x K) residuals.
        rgb, depth = jax.lax.map(jax.checkpoint(tile_fn), (lists, origins))
        return rgb, depth

    def loss(p, lists, boxes, dl):
        rgb, _ = rasterise(p, lists, boxes)
        return jnp.sum(rgb * dl)

    fwd = jax.jit(rasterise)
    fwd_bwd = jax.jit(jax.value_and_grad(loss))
    # Same loss weights as the Rust bench: dL/dC = ((i % 7) - 3)·0.01 per image pixel i.
    img_i = (origins[:, None, 1] + local_px[None, :, 1]) * W + origins[:, None, 0] + local_px[None, :, 0]
    dl = ((jnp.mod(img_i, 7) - 3.0) * 0.01)[..., None] * jnp.ones(3)

    def timed(fn):
        times = []
        out = None
        for r in range(args.repeats + 1):
            t = time.perf_counter()
            lists, boxes = bin_tiles(params)
            out = jax.block_until_ready(fn(lists, boxes))
            if r > 0:  # the first run compiles
                times.append((time.perf_counter() - t) * 1e3)
        return sorted(times)[len(times) // 2], out

    ms_f, (rgb, _) = timed(lambda l, b: fwd(params, l, b))
    print(f"ref forward median_ms {ms_f:.3f}", flush=True)
    inside = (origins[:, None, 0] + local_px[None, :, 0] < W) & (origins[:, None, 1] + local_px[None, :, 1] < H)
    print(f"ref image_sum {float(jnp.sum(jnp.where(inside[..., None], rgb, 0.0))):.6f}", flush=True)
    ms_fb, _ = timed(lambda l, b: fwd_bwd(params, l, b, dl))
    print(f"ref forward_backward median_ms {ms_fb:.3f}", flush=True)


if __name__ == "__main__":
    main()
