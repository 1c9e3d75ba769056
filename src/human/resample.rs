//! Interpolation on a common clock: linear for positions and angles, slerp for orientations.

use nalgebra::{UnitQuaternion, Vector3};

/// Monotone search position in a strictly increasing time array. Resampling visits times in
/// increasing order, so the cursor only moves forward: the whole pass is O(n + m), no bisection.
#[derive(Debug, Default, Clone, Copy)]
pub struct Cursor {
    i: usize,
}

impl Cursor {
    /// The interval `[t[i], t[i+1]]` containing `t` and the fraction `a` of the way through it.
    /// Times outside the array clamp to its ends (`a` = 0 or 1). `ts` must be strictly increasing
    /// and non-empty; `t` must not decrease between calls.
    pub fn locate(&mut self, ts: &[f64], t: f64) -> (usize, f64) {
        let last = ts.len() - 1;
        if last == 0 || t <= ts[0] {
            return (0, 0.0);
        }
        if t >= ts[last] {
            self.i = last - 1;
            return (last - 1, 1.0);
        }
        while self.i + 1 < last && ts[self.i + 1] <= t {
            self.i += 1;
        }
        let i = self.i;
        (i, (t - ts[i]) / (ts[i + 1] - ts[i]))
    }
}

pub fn lerp(a: &Vector3<f64>, b: &Vector3<f64>, s: f64) -> Vector3<f64> {
    a + (b - a) * s
}

/// Spherical linear interpolation along the shorter arc (nalgebra flips the sign of `b` when the
/// quaternions are in opposite hemispheres). For nearly identical rotations, where the slerp
/// weights are 0/0, normalised linear interpolation is exact to rounding.
pub fn slerp(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, s: f64) -> UnitQuaternion<f64> {
    a.try_slerp(b, s, 1e-9).unwrap_or_else(|| {
        let bq = if a.coords.dot(&b.coords) < 0.0 {
            -b.into_inner()
        } else {
            b.into_inner()
        };
        UnitQuaternion::from_quaternion(a.into_inner() * (1.0 - s) + bq * s)
    })
}

/// Resample scalar samples `(ts, ys)` at times `out_t` by linear interpolation.
pub fn resample_linear(ts: &[f64], ys: &[f64], out_t: &[f64]) -> Vec<f64> {
    let mut c = Cursor::default();
    out_t
        .iter()
        .map(|&t| {
            let (i, a) = c.locate(ts, t);
            let j = (i + 1).min(ts.len() - 1);
            ys[i] + a * (ys[j] - ys[i])
        })
        .collect()
}

/// Resample orientations `(ts, qs)` at times `out_t` by slerp.
pub fn resample_slerp(
    ts: &[f64],
    qs: &[UnitQuaternion<f64>],
    out_t: &[f64],
) -> Vec<UnitQuaternion<f64>> {
    let mut c = Cursor::default();
    out_t
        .iter()
        .map(|&t| {
            let (i, a) = c.locate(ts, t);
            let j = (i + 1).min(ts.len() - 1);
            slerp(&qs[i], &qs[j], a)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_signals_are_reproduced_exactly_on_an_irregular_grid() {
        let ts: Vec<f64> = (0..50)
            .map(|k| k as f64 / 240.0 + 1e-4 * ((k * 7) % 3) as f64)
            .collect();
        let ys: Vec<f64> = ts.iter().map(|t| 3.0 * t - 0.5).collect();
        let out: Vec<f64> = (0..20).map(|k| 0.001 + k as f64 / 100.0).collect();
        let r = resample_linear(&ts, &ys, &out);
        for (t, y) in out.iter().zip(&r) {
            assert!((y - (3.0 * t - 0.5)).abs() < 1e-12, "{t}: {y}");
        }
    }

    #[test]
    fn samples_on_the_grid_are_returned_unchanged_and_ends_clamp() {
        let ts = [0.0, 0.5, 1.5, 2.0];
        let ys = [1.0, -2.0, 4.0, 0.25];
        assert_eq!(resample_linear(&ts, &ys, &ts), ys.to_vec());
        assert_eq!(resample_linear(&ts, &ys, &[-1.0, 3.0]), vec![1.0, 0.25]);
    }

    #[test]
    fn slerp_of_a_constant_rate_rotation_is_exact() {
        // q(t) = exp(ω t / 2) about a fixed axis: slerp between any two samples is exact.
        let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
        let w = 2.5; // rad/s
        let q = |t: f64| UnitQuaternion::from_scaled_axis(axis * (w * t));
        let ts: Vec<f64> = (0..30).map(|k| k as f64 / 90.0).collect();
        let qs: Vec<_> = ts.iter().map(|&t| q(t)).collect();
        let out: Vec<f64> = (0..40).map(|k| k as f64 / 130.0).collect();
        for (t, r) in out.iter().zip(resample_slerp(&ts, &qs, &out)) {
            assert!(r.angle_to(&q(*t)) < 1e-12, "t = {t}");
        }
    }

    #[test]
    fn slerp_takes_the_short_way_across_hemispheres() {
        let a = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.2));
        let b = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.6));
        // The same rotation as b with the opposite sign.
        let b_neg = UnitQuaternion::new_unchecked(-b.into_inner());
        let m = slerp(&a, &b_neg, 0.5);
        let expected = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 0.4));
        assert!(m.angle_to(&expected) < 1e-12);
        // Identical inputs (0/0 weights) still interpolate.
        assert!(slerp(&a, &a, 0.3).angle_to(&a) < 1e-12);
    }
}
