"""The renderer and the Fisher information from Python: the values of the Rust crates (the
fixture tests/splat_fixture.rs checks on the Rust side), finite differences of the render, and
the errors bad input gets."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import activemap


def gaussians(fx: dict, dtype) -> activemap.Gaussians:
    g = fx["gaussians"]
    return activemap.Gaussians(
        means=np.array(g["means"], dtype=dtype).reshape(-1, 3),
        sh_dc=np.array(g["sh_dc"], dtype=dtype).reshape(-1, 3),
        rotations=np.array(g["rotations"], dtype=dtype).reshape(-1, 4),
        opacity_logits=np.array(g["opacity_logits"], dtype=dtype),
        log_scales=np.array(g["log_scales"], dtype=dtype).reshape(-1, 3),
    )


def pose(fx: dict) -> np.ndarray:
    return np.array(fx["pose"]).reshape(4, 4)


@pytest.mark.parametrize("precision", ["f32", "f64"])
def test_render_and_fisher_equal_the_rust_values(splat_fixture, precision):
    dtype = np.float32 if precision == "f32" else np.float64
    g = gaussians(splat_fixture, dtype)
    want = splat_fixture[precision]
    k = splat_fixture["intrinsics"]
    out = activemap.render(g, pose(splat_fixture), k)
    w, h = k[0], k[1]
    assert out.colour.shape == (h, w, 3) and out.colour.dtype == dtype
    assert out.depth.shape == (h, w) and out.opacity.shape == (h, w)
    np.testing.assert_array_equal(out.colour.ravel(), np.array(want["colour"], dtype=dtype))
    np.testing.assert_array_equal(out.depth.ravel(), np.array(want["depth"], dtype=dtype))
    np.testing.assert_array_equal(out.opacity.ravel(), np.array(want["opacity"], dtype=dtype))
    assert out.opacity.max() > 0.5, "the fixture scene is seen"

    info = activemap.view_fisher(g, pose(splat_fixture), k)
    assert info.colour.shape == (len(g), 14) and info.colour.dtype == dtype
    np.testing.assert_array_equal(info.colour.ravel(), np.array(want["fisher_colour"], dtype=dtype))
    np.testing.assert_array_equal(info.depth.ravel(), np.array(want["fisher_depth"], dtype=dtype))
    np.testing.assert_array_equal(info.pose_colour.ravel(), want["pose_colour"])
    np.testing.assert_array_equal(info.pose_depth.ravel(), want["pose_depth"])


def test_view_information_eig_and_localisation_cost_equal_the_rust_values(splat_fixture):
    g = gaussians(splat_fixture, np.float32)
    vi = splat_fixture["view_information"]
    got = activemap.view_information(g, pose(splat_fixture), splat_fixture["intrinsics"])
    np.testing.assert_array_equal(got.diagonal.ravel(), vi["diagonal"])
    np.testing.assert_array_equal(got.pose.ravel(), vi["pose"])
    assert got.low_opacity_pixels == vi["low_opacity_pixels"]
    prior = np.array(splat_fixture["prior"]).reshape(-1, 14)
    assert activemap.eig(got, prior) == splat_fixture["eig"]
    assert activemap.eig(got.diagonal, prior) == splat_fixture["eig"]
    assert activemap.localisation_cost(got.pose) == splat_fixture["localisation_cost"]
    assert activemap.localisation_cost(np.zeros((6, 6))) == float("inf")


def images(g: activemap.Gaussians, p: np.ndarray, k) -> tuple[np.ndarray, np.ndarray]:
    # The centre depth model: the one the Fisher pass differentiates.
    out = activemap.render(g, p, k, depth_model="centre")
    return out.colour, out.depth


def test_fisher_diagonal_equals_finite_differences_of_the_render(splat_fixture):
    """diag_k = sum over pixels (and channels) of (d image / d w_k)^2, with the derivative from
    central differences of float64 renders."""
    g = gaussians(splat_fixture, np.float64)
    p = pose(splat_fixture)
    k = splat_fixture["intrinsics"]
    info = activemap.view_fisher(g, p, k)
    groups = ["means", "sh_dc", "rotations", "opacity_logits", "log_scales"]
    offsets = [0, 3, 6, 10, 11]
    checked = 0
    for i in range(len(g)):
        for group, offset in zip(groups, offsets):
            array = getattr(g, group)
            for j in range(1 if array.ndim == 1 else array.shape[1]):
                h = 1e-6
                plus = activemap.Gaussians(**{n: getattr(g, n).copy() for n in groups})
                minus = activemap.Gaussians(**{n: getattr(g, n).copy() for n in groups})
                index = (i,) if array.ndim == 1 else (i, j)
                getattr(plus, group)[index] += h
                getattr(minus, group)[index] -= h
                (cp, dp), (cm, dm) = images(plus, p, k), images(minus, p, k)
                fd_colour = np.sum(((cp - cm) / (2 * h)) ** 2)
                fd_depth = np.sum(((dp - dm) / (2 * h)) ** 2)
                want_c, want_d = info.colour[i, offset + j], info.depth[i, offset + j]
                assert fd_colour == pytest.approx(want_c, rel=2e-4, abs=1e-9), (i, group, j)
                assert fd_depth == pytest.approx(want_d, rel=2e-4, abs=1e-9), (i, group, j)
                checked += want_c > 1e-6
    assert checked > 40, "most parameters of the fixture scene are informed"


def se3_exp(tau: np.ndarray) -> np.ndarray:
    """Exp of tau = [rho, theta] as a 4x4 matrix (SE(3), left Jacobian for the translation)."""
    rho, theta = tau[:3], tau[3:]
    angle = np.linalg.norm(theta)
    hat = np.array([[0, -theta[2], theta[1]], [theta[2], 0, -theta[0]], [-theta[1], theta[0], 0]])
    if angle < 1e-12:
        r, v = np.eye(3) + hat, np.eye(3) + 0.5 * hat
    else:
        a, b = np.sin(angle) / angle, (1 - np.cos(angle)) / angle**2
        c = (angle - np.sin(angle)) / angle**3
        r = np.eye(3) + a * hat + b * hat @ hat
        v = np.eye(3) + b * hat + c * hat @ hat
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r, v @ rho
    return out


def test_pose_information_equals_finite_differences_of_the_render(splat_fixture):
    """J^T J for the left update T_cw <- Exp(tau) T_cw, i.e. T_wc <- T_wc Exp(-tau)."""
    g = gaussians(splat_fixture, np.float64)
    p = pose(splat_fixture)
    k = splat_fixture["intrinsics"]
    info = activemap.view_fisher(g, p, k)
    h = 1e-6
    jc, jd = [], []
    for axis in range(6):
        tau = np.zeros(6)
        tau[axis] = h
        (cp, dp) = images(g, p @ se3_exp(-tau), k)
        (cm, dm) = images(g, p @ se3_exp(tau), k)
        jc.append(((cp - cm) / (2 * h)).ravel())
        jd.append(((dp - dm) / (2 * h)).ravel())
    jc, jd = np.array(jc), np.array(jd)
    np.testing.assert_allclose(jc @ jc.T, info.pose_colour, rtol=1e-4, atol=1e-6 * np.abs(info.pose_colour).max())
    np.testing.assert_allclose(jd @ jd.T, info.pose_depth, rtol=1e-4, atol=1e-6 * np.abs(info.pose_depth).max())


def test_outputs_are_numpy_arrays_over_the_rust_buffers(splat_fixture):
    g = gaussians(splat_fixture, np.float32)
    out = activemap.render(g, pose(splat_fixture), activemap.Intrinsics(32, 24, 28, 28, 15.5, 11.5))
    for image in out:
        assert not image.flags.owndata and image.base is not None  # the Rust Vec, not a copy
        assert image.flags.c_contiguous


def test_renders_run_in_parallel_threads(splat_fixture):
    """The GIL is released while Rust renders: threads give the same images as one call."""
    g = gaussians(splat_fixture, np.float32)
    k, p = splat_fixture["intrinsics"], pose(splat_fixture)
    want = activemap.render(g, p, k).colour
    results: list[np.ndarray] = []
    threads = [threading.Thread(target=lambda: results.append(activemap.render(g, p, k).colour)) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 4 and all(np.array_equal(r, want) for r in results)


def test_natural_units_and_dict_input(splat_fixture):
    g = activemap.Gaussians.from_natural(
        means=[[0, 0, 2]], colours=[[0.8, 0.2, 0.1]], rotations=[[1, 0, 0, 0]],
        opacities=[0.7], scales=[[0.2, 0.2, 0.2]],
    )
    np.testing.assert_allclose(g.colours, [[0.8, 0.2, 0.1]], rtol=1e-6)
    np.testing.assert_allclose(g.opacities, [0.7], rtol=1e-6)
    np.testing.assert_allclose(g.covariances()[0], np.eye(3) * 0.04, rtol=1e-5)
    k = activemap.Intrinsics.from_hfov(16, 16, 90)
    a = activemap.render(g, np.eye(4), k)
    b = activemap.render({f: getattr(g, f) for f in ("means", "sh_dc", "rotations", "opacity_logits", "log_scales")}, np.eye(4), k)
    np.testing.assert_array_equal(a.colour, b.colour)
    c = activemap.render(g, np.eye(4), {"width": 16, "height": 16, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy})
    np.testing.assert_array_equal(a.colour, c.colour)
    centre = a.colour[7:9, 7:9].mean(axis=(0, 1))
    assert centre[0] > centre[1] > centre[2] > 0  # reddish, seen


def test_bad_input_raises_errors_naming_what_is_wrong(splat_fixture):
    g = gaussians(splat_fixture, np.float32)
    k, p = splat_fixture["intrinsics"], pose(splat_fixture)
    with pytest.raises(ValueError, match=r"means must have shape \(N, 3\)"):
        activemap.render({**g.__dict__, "means": g.means[:, :2]}, p, k)
    with pytest.raises(ValueError, match=r"rotations must have shape \(6, 4\)"):
        activemap.render({**g.__dict__, "rotations": g.rotations[:5]}, p, k)
    with pytest.raises(TypeError, match="means must hold real numbers"):
        activemap.render({**g.__dict__, "means": np.array([["a"] * 3] * 6)}, p, k)
    with pytest.raises(ValueError, match="4x4"):
        activemap.render(g, np.eye(3), k)
    with pytest.raises(ValueError, match="not a rotation"):
        activemap.render(g, np.diag([2.0, 1, 1, 1]), k)
    with pytest.raises(ValueError, match="intrinsics must be"):
        activemap.render(g, p, (32, 24, 28))
    with pytest.raises(ValueError, match="invalid camera"):
        activemap.render(g, p, (0, 24, 28, 28, 15.5, 11.5))
    with pytest.raises(ValueError, match="depth_model must be"):
        activemap.render(g, p, k, depth_model="flat")
    with pytest.raises(ValueError, match="mode must be"):
        activemap.view_fisher(g, p, k, mode="bogus")
    with pytest.raises(ValueError, match="prior must have shape"):
        activemap.eig(np.zeros((6, 14)), np.ones((6, 13)))
    with pytest.raises(ValueError, match="prior row 0"):
        activemap.eig(np.ones((6, 14)), np.zeros((6, 14)))
    with pytest.raises(ValueError, match="6x6"):
        activemap.localisation_cost(np.eye(5))
    with pytest.raises(TypeError, match="opacity_logits"):
        activemap.render({"means": g.means}, p, k)
