//! The scalar type of the renderer. Production runs in `f32` for speed; the finite-difference
//! gradient tests run the very same code in `f64`.

use nalgebra::RealField;

/// A floating-point scalar the renderer is generic over (implemented for `f32` and `f64`).
pub trait Real: RealField + Copy + Default + Send + Sync + std::fmt::Debug + 'static {
    /// Converts from `f64` (rounding for `f32`).
    fn of(x: f64) -> Self;
    /// Converts to `f64` (exact).
    fn to_f64(self) -> f64;
    /// Converts from `f32` (exact).
    fn of_f32(x: f32) -> Self;
    /// Converts to `f32` (rounding for `f64`).
    fn to_f32(self) -> f32;
    /// `e^self` for the per-pixel loops: branch-free so that the compiler vectorises it.
    /// `f32`: Cephes-style range reduction and polynomial (≈ 2 ulp on `[−87, 88]`, inputs
    /// clamped there); `f64`: the exact library `exp`, so the f64 gradient checks see the
    /// true function.
    fn exp_fast(self) -> Self;
}

/// Branch-free `e^x` in `f32` (Cephes `expf`): `x = n·ln2 + r` with `|r| ≤ ln2/2`, a
/// degree-6 polynomial for `e^r`, and `2^n` assembled in the exponent bits.
#[inline(always)]
fn exp_f32(x: f32) -> f32 {
    // 1.5·2^23: adding it rounds to an integer held in the low mantissa bits.
    const SHIFTER: f32 = 12_582_912.0;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let shifted = x * std::f32::consts::LOG2_E + SHIFTER;
    let n = shifted - SHIFTER;
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = ((((1.987_569_1e-4 * r + 1.398_199_9e-3) * r + 8.333_452e-3) * r + 4.166_579_6e-2) * r
        + 1.666_666_5e-1)
        * r
        + 0.5;
    let e_r = p * r * r + r + 1.0;
    // Wrapping integer ops: the clamp keeps n in [−126, 127], so they never wrap, and without
    // the overflow checks of debug builds the pixel loops that call this vectorise.
    let n_int = (shifted.to_bits() as i32).wrapping_sub(SHIFTER.to_bits() as i32);
    e_r * f32::from_bits((n_int.wrapping_add(127) << 23) as u32)
}

impl Real for f32 {
    #[inline(always)]
    fn of(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn of_f32(x: f32) -> Self {
        x
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        exp_f32(self)
    }
}

impl Real for f64 {
    #[inline(always)]
    fn of(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    #[inline(always)]
    fn of_f32(x: f32) -> Self {
        x as f64
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    #[inline(always)]
    fn exp_fast(self) -> Self {
        self.exp()
    }
}

#[cfg(test)]
mod tests {
    use super::Real;

    #[test]
    fn fast_f32_exp_matches_the_f64_library_exp() {
        // Dense sweep of the range the renderer uses (σ ∈ [0, 20]) and the clamp range.
        let mut worst = 0.0f64;
        for i in 0..=200_000 {
            let x = -87.0 + 175.0 * i as f64 / 200_000.0;
            let xf = x as f32;
            let exact = (xf as f64).exp();
            let rel = ((xf.exp_fast() as f64) - exact).abs() / exact;
            worst = worst.max(rel);
        }
        assert!(
            worst < 4.0 * f32::EPSILON as f64,
            "worst relative error {worst}"
        );
        assert_eq!(0.0f32.exp_fast(), 1.0);
        // Clamped, finite, and never NaN far outside the range.
        assert!((-1.0e30f32).exp_fast() >= 0.0 && (-1.0e30f32).exp_fast() < 1e-37);
        assert!(1.0e30f32.exp_fast().is_finite());
    }
}
