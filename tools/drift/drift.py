#!/usr/bin/env python3
"""Drift characterisation of one run folder.
usage: drift.py RUN_DIR [--csv OUT.csv]
Raw error: estimate taken to the true frame by the first pose pair (T = T_true0 * T_est0^-1),
as the evaluator's jump check does. Aligned: Umeyama SE(3) on positions (as ate_m).
Yaw/pitch/roll error: from R_err = R_true^T * R_est_in_true (camera frame), expressed as the
rotation angle about world z of the forward axis, plus tilt of the camera's up axis."""
import sys, json, os, re
import numpy as np

def quat2R(q):  # x y z w
    x, y, z, w = q / np.linalg.norm(q)
    return np.array([[1-2*(y*y+z*z), 2*(x*y-z*w), 2*(x*z+y*w)],
                     [2*(x*y+z*w), 1-2*(x*x+z*z), 2*(y*z-x*w)],
                     [2*(x*z-y*w), 2*(y*z+x*w), 1-2*(x*x+y*y)]])

def load(path):
    a = np.loadtxt(path)
    t = a[:, 0]; p = a[:, 1:4]; R = np.array([quat2R(q) for q in a[:, 4:8]])
    return t, p, R

def umeyama(src, dst):
    ms, md = src.mean(0), dst.mean(0)
    C = (dst - md).T @ (src - ms) / len(src)
    U, S, Vt = np.linalg.svd(C)
    s = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0: s[2, 2] = -1
    R = U @ s @ Vt
    return R, md - R @ ms

def wrap(a): return (a + np.pi) % (2 * np.pi) - np.pi

def analyse(run):
    te, pe, Re = load(os.path.join(run, 'trajectory_est.tum'))
    tt, pt, Rt = load(os.path.join(run, 'trajectory_true.tum'))
    n = min(len(te), len(tt)); assert np.allclose(te[:n], tt[:n])
    te, pe, Re, pt, Rt = te[:n], pe[:n], Re[:n], pt[:n], Rt[:n]
    # camera axes: find which camera axis is world-up in the true first pose
    up_idx = np.argmax(np.abs(Rt[0][2, :])); up_sign = np.sign(Rt[0][2, up_idx])
    fwd_idx = 2  # optical axis (OpenCV z forward) -- checked below
    # anchor
    A_R = Rt[0] @ Re[0].T; A_t = pt[0] - A_R @ pe[0]
    pe_w = pe @ A_R.T + A_t
    Re_w = np.einsum('ij,njk->nik', A_R, Re)
    err = np.linalg.norm(pe_w - pt, axis=1)
    exy = np.linalg.norm((pe_w - pt)[:, :2], axis=1)
    ez = (pe_w - pt)[:, 2]
    # heading of forward axis
    def heading(R): f = R[:, :, fwd_idx]; return np.arctan2(f[:, 1], f[:, 0])
    yaw_t = np.unwrap(heading(Rt)); yaw_e = np.unwrap(heading(Re_w))
    eyaw = np.degrees(wrap(yaw_e - yaw_t))
    # tilt: angle between estimated camera-up axis and world up (true is level)
    up_e = up_sign * Re_w[:, :, up_idx]
    tilt = np.degrees(np.arccos(np.clip(up_e[:, 2], -1, 1)))
    up_t = up_sign * Rt[:, :, up_idx]; tilt_t = np.degrees(np.arccos(np.clip(up_t[:, 2], -1, 1)))
    # aligned
    R, t = umeyama(pe_w, pt)
    ea = np.linalg.norm(pe_w @ R.T + t - pt, axis=1)
    # motion per step (true)
    dstep = np.r_[0, np.linalg.norm(np.diff(pt, axis=0), axis=1)]
    dyaw = np.r_[0, np.degrees(np.abs(wrap(np.diff(yaw_t))))]
    return dict(t=te, err=err, exy=exy, ez=ez, eyaw=eyaw, tilt=tilt, tilt_t=tilt_t, ea=ea,
                dstep=dstep, dyaw=dyaw, pe_w=pe_w, pt=pt, yaw_t=yaw_t, yaw_e=yaw_e,
                align_yaw=np.degrees(np.arctan2(R[1, 0], R[0, 0])), up_idx=up_idx)

def events(run):
    ev = {}
    p = os.path.join(run, 'logs', 'tracker.stderr.log')
    for line in open(p):
        m = re.match(r'tracker: frame (\d+): (.*)', line.strip())
        if m: ev.setdefault(int(m.group(1)), []).append(m.group(2))
    return ev

def refine_step(run):
    p = os.path.join(run, 'fisher.csv')
    if not os.path.exists(p): return None
    for line in open(p).readlines()[1:]:
        f = line.split(',')
        if f[1] == 'true': return int(f[0])
    return None

def cov99(run):
    for line in open(os.path.join(run, 'coverage.csv')).readlines()[1:]:
        s, c = line.split(',')
        if float(c) >= 0.99: return int(s)
    return None

if __name__ == '__main__':
    run = sys.argv[1]
    d = analyse(run)
    n = len(d['err'])
    ev = events(run)
    print(f"run {run}")
    print(f"camera up axis index {d['up_idx']}; steps {n}; path {d['dstep'].sum():.1f} m; turned {d['dyaw'].sum():.0f} deg")
    print(f"refine starts (fisher.csv) at step {refine_step(run)}; coverage>=99% at {cov99(run)}")
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))
    print(f"raw: RMS {100*rms(d['err']):.1f} cm, final {100*d['err'][-1]:.1f} cm, max {100*d['err'].max():.1f} cm; aligned RMS {100*rms(d['ea']):.1f} cm (final {100*d['ea'][-1]:.1f}); alignment yaw {d['align_yaw']:.1f} deg")
    print(f"yaw err: final {d['eyaw'][-1]:.1f} deg, max |.| {np.abs(d['eyaw']).max():.1f}; z err final {100*d['ez'][-1]:.1f} cm, max |.| {100*np.abs(d['ez']).max():.1f}; tilt est final {d['tilt'][-1]:.2f} deg max {d['tilt'].max():.2f} (true tilt max {d['tilt_t'].max():.2f})")
    print(" step | err cm | xy cm | z cm | yaw deg | tilt deg | aligned cm | path m | turned deg")
    for k in list(range(0, n, 100)) + [n - 1]:
        print(f" {k:5d} | {100*d['err'][k]:6.1f} | {100*d['exy'][k]:5.1f} | {100*d['ez'][k]:5.1f} | {d['eyaw'][k]:7.2f} | {d['tilt'][k]:6.2f} | {100*d['ea'][k]:6.1f} | {d['dstep'][:k+1].sum():5.1f} | {d['dyaw'][:k+1].sum():6.0f}")
    if '--csv' in sys.argv:
        out = sys.argv[sys.argv.index('--csv') + 1]
        np.savetxt(out, np.c_[np.arange(n), d['err'], d['exy'], d['ez'], d['eyaw'], d['tilt'], d['ea'], d['dstep'], d['dyaw']],
                   delimiter=',', header='step,err,exy,ez,eyaw_deg,tilt_deg,err_aligned,dstep,dyaw_deg', fmt='%.6f', comments='')
