//! SE(3) exponential and logarithm with the tangent τ = [ρ, θ] (SPEC §2): ρ is the translational
//! part, θ the rotation vector. `Exp(τ)` is the matrix exponential of the twist
//! `[[θ]×, ρ; 0, 0]`, so that a left update `T ← Exp(τ)·T` moves `T` by τ expressed in the
//! frame `T` maps into.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// Skew-symmetric matrix `[v]×` with `[v]× w = v × w`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Left Jacobian of SO(3), `V(θ)`, which maps ρ to the translation of `Exp([ρ, θ])`.
pub fn so3_left_jacobian(theta: &Vector3<f64>) -> Matrix3<f64> {
    let angle = theta.norm();
    let k = hat(theta);
    if angle < 1e-6 {
        // Taylor series to third order keeps f64 accuracy near zero.
        Matrix3::identity() + 0.5 * k + k * k / 6.0
    } else {
        let a2 = angle * angle;
        Matrix3::identity()
            + (1.0 - angle.cos()) / a2 * k
            + (angle - angle.sin()) / (a2 * angle) * k * k
    }
}

/// Inverse of [`so3_left_jacobian`].
pub fn so3_left_jacobian_inv(theta: &Vector3<f64>) -> Matrix3<f64> {
    let angle = theta.norm();
    let k = hat(theta);
    if angle < 1e-6 {
        Matrix3::identity() - 0.5 * k + k * k / 12.0
    } else {
        let half = 0.5 * angle;
        let coef = (1.0 - half * half.cos() / half.sin()) / (angle * angle);
        Matrix3::identity() - 0.5 * k + coef * k * k
    }
}

/// `Exp(τ)` for τ = [ρ, θ] (SPEC §2).
pub fn exp(tau: &Vector6<f64>) -> Isometry3<f64> {
    let rho = Vector3::new(tau[0], tau[1], tau[2]);
    let theta = Vector3::new(tau[3], tau[4], tau[5]);
    let rotation = UnitQuaternion::from_scaled_axis(theta);
    let translation = so3_left_jacobian(&theta) * rho;
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

/// `Log(T)` = τ = [ρ, θ], the inverse of [`exp`] for rotation angles below π.
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    let theta = pose.rotation.scaled_axis();
    let rho = so3_left_jacobian_inv(&theta) * pose.translation.vector;
    Vector6::new(rho.x, rho.y, rho.z, theta.x, theta.y, theta.z)
}

/// Applies the left update `T ← Exp(τ)·T` of SPEC §2. The rotation is renormalised: a
/// product of unit quaternions drifts off unit norm by rounding, and `inverse()` (the
/// conjugate) then no longer inverts it, so chains of relative poses would amplify the
/// drift geometrically.
pub fn left_update(pose: &Isometry3<f64>, tau: &Vector6<f64>) -> Isometry3<f64> {
    normalized(&(exp(tau) * pose))
}

/// `pose` with its rotation quaternion rescaled to unit norm (see [`left_update`]).
pub fn normalized(pose: &Isometry3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(
        pose.translation,
        UnitQuaternion::new_normalize(*pose.rotation.quaternion()),
    )
}

/// The adjoint `Ad(T)` for τ = [ρ, θ]: `T·Exp(τ)·T⁻¹ = Exp(Ad(T)·τ)`, i.e.
/// `[[R, [t]×R], [0, R]]`. It moves a perturbation from the frame `T` maps from into the frame
/// it maps into, so that Gauss–Newton normal equations written for different frames can be
/// summed (`H' = Adᵀ H Ad`, `g' = Adᵀ g`).
pub fn adjoint(pose: &Isometry3<f64>) -> Matrix6<f64> {
    let r = *pose.rotation.to_rotation_matrix().matrix();
    let tr = hat(&pose.translation.vector) * r;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&tr);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

/// Left Jacobian of SE(3) for τ = [ρ, θ]: `Exp(τ + ε) ≈ Exp(J_l(τ)·ε)·Exp(τ)` to first order in
/// ε. Block form `[[V(θ), Q(ρ, θ)], [0, V(θ)]]` with `V` = [`so3_left_jacobian`] and `Q` the
/// closed form of Barfoot, *State Estimation for Robotics* (2017), eq. 7.86 (series limits below
/// 1e-4 rad). The pose graph needs it to linearise `Log` of a relative-pose error exactly.
pub fn se3_left_jacobian(tau: &Vector6<f64>) -> Matrix6<f64> {
    let rho = Vector3::new(tau[0], tau[1], tau[2]);
    let theta = Vector3::new(tau[3], tau[4], tau[5]);
    let v = so3_left_jacobian(&theta);
    let q = se3_q(&rho, &theta);
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&v);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&q);
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&v);
    j
}

/// Inverse of [`se3_left_jacobian`]: `[[V⁻¹, −V⁻¹·Q·V⁻¹], [0, V⁻¹]]`.
pub fn se3_left_jacobian_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
    let rho = Vector3::new(tau[0], tau[1], tau[2]);
    let theta = Vector3::new(tau[3], tau[4], tau[5]);
    let vi = so3_left_jacobian_inv(&theta);
    let q = se3_q(&rho, &theta);
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&vi);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-vi * q * vi));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&vi);
    j
}

/// Inverse right Jacobian of SE(3): `Log(Exp(τ)·Exp(ε)) ≈ τ + J_r⁻¹(τ)·ε`, with
/// `J_r(τ) = J_l(−τ)`.
pub fn se3_right_jacobian_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
    se3_left_jacobian_inv(&(-tau))
}

/// The off-diagonal block `Q(ρ, θ)` of [`se3_left_jacobian`] (Barfoot eq. 7.86).
fn se3_q(rho: &Vector3<f64>, theta: &Vector3<f64>) -> Matrix3<f64> {
    let angle = theta.norm();
    let (p, t) = (hat(rho), hat(theta));
    let (a, b, c) = if angle < 1e-4 {
        // Limits of the three coefficients at θ → 0 (their next terms are O(θ²)).
        (1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0)
    } else {
        let (s, co) = (angle.sin(), angle.cos());
        let a2 = angle * angle;
        (
            (angle - s) / (a2 * angle),
            (a2 + 2.0 * co - 2.0) / (2.0 * a2 * a2),
            (2.0 * angle - 3.0 * s + angle * co) / (2.0 * a2 * a2 * angle),
        )
    };
    0.5 * p
        + a * (t * p + p * t + t * p * t)
        + b * (t * t * p + p * t * t - 3.0 * t * p * t)
        + c * (t * p * t * t + t * t * p * t)
}

/// Translation distance (metres) and rotation angle (radians) between two poses.
pub fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    let delta = a.inverse() * b;
    (delta.translation.vector.norm(), delta.rotation.angle())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Isometry3<f64>, b: &Isometry3<f64>, tol: f64) -> bool {
        let (t, r) = pose_error(a, b);
        t < tol && r < tol
    }

    #[test]
    fn chained_relative_poses_stay_rigid() {
        // The tracker's pattern: T_k = R·(R⁻¹·T_{k−1}·Δ) updated in place, with R = T_{k−1}.
        // Without renormalisation the quaternion norm error triples per frame and the
        // "rotation" starts scaling vectors after a few dozen frames.
        let delta = exp(&Vector6::new(0.0, 0.0, 0.05, 0.001, 0.002, -0.001));
        let mut pose = exp(&Vector6::new(1.0, 2.0, 0.5, 0.3, -1.2, 2.0));
        for _ in 0..200 {
            let reference = pose;
            let relative = reference.inverse() * pose * delta;
            let relative = left_update(&relative, &Vector6::new(1e-4, 0.0, 0.0, 0.0, 1e-4, 0.0));
            pose = reference * relative;
        }
        assert!((pose.rotation.quaternion().norm() - 1.0).abs() < 1e-12);
        let unit = pose * nalgebra::Point3::new(1.0, 0.0, 0.0) - pose * nalgebra::Point3::origin();
        assert!((unit.norm() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn adjoint_conjugates_the_exponential() {
        let t = exp(&Vector6::new(0.7, -1.2, 0.4, 0.3, -0.5, 0.9));
        for tau in [
            Vector6::new(0.01, 0.02, -0.03, 0.0, 0.0, 0.0),
            Vector6::new(0.0, 0.0, 0.0, 0.02, -0.01, 0.03),
            Vector6::new(0.05, -0.02, 0.01, -0.03, 0.04, 0.02),
        ] {
            let conjugated = t * exp(&tau) * t.inverse();
            let via_adjoint = exp(&(adjoint(&t) * tau));
            assert!(close(&conjugated, &via_adjoint, 1e-12), "{tau}");
        }
    }

    #[test]
    fn exp_log_round_trip() {
        let taus = [
            Vector6::new(0.1, -0.2, 0.3, 0.4, -0.5, 0.6),
            Vector6::new(1.0, 2.0, 3.0, 1e-9, 0.0, -1e-9),
            Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            Vector6::new(-0.5, 0.1, 0.0, 0.0, 3.0, 0.0),
        ];
        for tau in taus {
            let back = log(&exp(&tau));
            assert!((back - tau).norm() < 1e-9, "{tau} -> {back}");
        }
    }

    #[test]
    fn exp_matches_matrix_exponential_series() {
        // Independent truth: the power series of the 4x4 twist matrix.
        let tau = Vector6::new(0.3, -0.1, 0.2, 0.5, 0.2, -0.4);
        let mut twist = nalgebra::Matrix4::<f64>::zeros();
        twist
            .fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&hat(&Vector3::new(tau[3], tau[4], tau[5])));
        twist[(0, 3)] = tau[0];
        twist[(1, 3)] = tau[1];
        twist[(2, 3)] = tau[2];
        let mut term = nalgebra::Matrix4::<f64>::identity();
        let mut sum = term;
        for k in 1..30 {
            term = term * twist / k as f64;
            sum += term;
        }
        let ours = exp(&tau).to_homogeneous();
        assert!((ours - sum).norm() < 1e-12);
    }

    #[test]
    fn left_jacobian_inverse_is_inverse() {
        for theta in [Vector3::new(0.1, 0.2, -0.3), Vector3::new(1e-8, 0.0, 0.0)] {
            let p = so3_left_jacobian(&theta) * so3_left_jacobian_inv(&theta);
            assert!((p - Matrix3::identity()).norm() < 1e-10);
        }
    }

    /// The SE(3) Jacobians against central differences (f64): `Log(Exp(ε)·Exp(τ))` and
    /// `Log(Exp(τ)·Exp(ε))` around ε = 0 give `J_l⁻¹` and `J_r⁻¹` column by column, at a large
    /// and a near-zero rotation; `J_l·J_l⁻¹ = I`.
    #[test]
    fn se3_jacobians_match_finite_differences() {
        for tau in [
            Vector6::new(0.4, -0.7, 0.2, 0.9, -0.4, 0.6),
            Vector6::new(-1.1, 0.3, 0.8, 2e-5, -1e-5, 3e-5),
            Vector6::new(0.2, 0.1, -0.3, 0.0, 0.0, 0.0),
        ] {
            let h = 1e-6;
            let mut left = Matrix6::zeros();
            let mut right = Matrix6::zeros();
            for k in 0..6 {
                let mut e = Vector6::zeros();
                e[k] = h;
                let d_left =
                    (log(&(exp(&e) * exp(&tau))) - log(&(exp(&-e) * exp(&tau)))) / (2.0 * h);
                let d_right =
                    (log(&(exp(&tau) * exp(&e))) - log(&(exp(&tau) * exp(&-e)))) / (2.0 * h);
                left.set_column(k, &d_left);
                right.set_column(k, &d_right);
            }
            let jl_inv = se3_left_jacobian_inv(&tau);
            let jr_inv = se3_right_jacobian_inv(&tau);
            assert!(
                (left - jl_inv).norm() < 1e-7,
                "J_l⁻¹ at {tau}: {left} vs {jl_inv}"
            );
            assert!(
                (right - jr_inv).norm() < 1e-7,
                "J_r⁻¹ at {tau}: {right} vs {jr_inv}"
            );
            let product = se3_left_jacobian(&tau) * jl_inv;
            let off = (product - Matrix6::identity()).norm();
            assert!(off < 1e-8, "J_l·J_l⁻¹ is {off} from I at {tau}");
        }
    }

    #[test]
    fn left_update_composes() {
        let t = exp(&Vector6::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.3));
        let tau = Vector6::new(0.0, 0.1, 0.0, 0.2, 0.0, 0.0);
        assert!(close(&left_update(&t, &tau), &(exp(&tau) * t), 1e-12));
    }
}
