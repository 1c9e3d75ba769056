//! A fused `sin`/`cos` for FK's joint angles.
//!
//! Hand-rolled because `f64::sin_cos` is two separate libm calls, each with its own range
//! reduction, and those calls were most of the instructions of FK on a 7-DoF arm (callgrind,
//! see `benches/kinematics.rs`). This shares one reduction between both and evaluates the
//! fdlibm kernel polynomials (`__kernel_sin`/`__kernel_cos`, Sun Microsystems, freely
//! redistributable), inlined and branch-light. Accuracy: within a couple of ulp of libm for
//! |x| ≤ 2^19·π/2 (checked against `f64::sin_cos` in the tests); larger or non-finite
//! arguments fall back to libm.

// The constants are fdlibm's decimal literals verbatim, so they can be checked against it.
#![allow(clippy::excessive_precision)]

/// π/2 split so that `k * PIO2_HI` is exact for |k| < 2^20 (33 significant bits).
const PIO2_HI: f64 = 1.570_796_326_734_125_614_17e+00;
/// π/2 − PIO2_HI.
const PIO2_LO: f64 = 6.077_100_506_506_192_249_32e-11;
const TWO_OVER_PI: f64 = std::f64::consts::FRAC_2_PI;
/// Adding and subtracting 1.5·2^52 rounds to the nearest integer without a libm call.
const ROUND_MAGIC: f64 = 6_755_399_441_055_744.0;
/// Beyond this the two-part reduction loses accuracy; libm takes over.
const REDUCE_LIMIT: f64 = 823_549.6;

const S1: f64 = -1.666_666_666_666_663_243_48e-01;
const S2: f64 = 8.333_333_333_322_489_461_24e-03;
const S3: f64 = -1.984_126_982_985_794_931_34e-04;
const S4: f64 = 2.755_731_370_707_006_767_89e-06;
const S5: f64 = -2.505_076_025_340_686_341_95e-08;
const S6: f64 = 1.589_690_995_211_550_102_21e-10;

const C1: f64 = 4.166_666_666_666_660_190_37e-02;
const C2: f64 = -1.388_888_888_887_410_957_49e-03;
const C3: f64 = 2.480_158_728_947_672_941_78e-05;
const C4: f64 = -2.755_731_435_139_066_330_35e-07;
const C5: f64 = 2.087_572_321_298_174_827_90e-09;
const C6: f64 = -1.135_964_755_778_819_482_65e-11;

/// `(sin x, cos x)`.
#[inline]
pub(crate) fn sin_cos(x: f64) -> (f64, f64) {
    if x.is_nan() || x.abs() >= REDUCE_LIMIT {
        return x.sin_cos();
    }
    let kf = (x * TWO_OVER_PI + ROUND_MAGIC) - ROUND_MAGIC;
    let r = (x - kf * PIO2_HI) - kf * PIO2_LO;
    let z = r * r;
    let s = r + r * z * (S1 + z * (S2 + z * (S3 + z * (S4 + z * (S5 + z * S6)))));
    let cr = z * (C1 + z * (C2 + z * (C3 + z * (C4 + z * (C5 + z * C6)))));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let c = w + (((1.0 - w) - hz) + z * cr);
    match (kf as i64) & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn matches_libm_over_joint_ranges_and_quadrant_boundaries() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let check = |x: f64| {
            let (s, c) = sin_cos(x);
            let (s0, c0) = x.sin_cos();
            assert!(
                (s - s0).abs() <= 1e-15 && (c - c0).abs() <= 1e-15,
                "x = {x}: ({s}, {c}) vs ({s0}, {c0})"
            );
        };
        for _ in 0..200_000 {
            check(rng.random_range(-20.0..20.0));
        }
        for _ in 0..20_000 {
            check(rng.random_range(-1e5..1e5));
        }
        for k in -40..=40 {
            let b = k as f64 * std::f64::consts::FRAC_PI_4;
            for d in [-1e-12, 0.0, 1e-12] {
                check(b + d);
            }
        }
        check(0.0);
        check(-0.0);
        check(1e-300);
        check(1e7);
        assert!(sin_cos(f64::NAN).0.is_nan() && sin_cos(f64::INFINITY).1.is_nan());
    }
}
