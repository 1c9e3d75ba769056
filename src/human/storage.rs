//! Compact flat representation of derived frames for the store (DESIGN §6: numeric arrays as
//! little-endian BLOBs, not JSON text).
//!
//! One row of [`FRAME_WIDTH`] f64 per frame:
//! `t | shoulder xyz | elbow xyz | wrist xyz, wrist quat wxyz | 5 × (tip xyz, tip quat wxyz) |
//! 22 glove angles`.

use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion};

use super::HumanFrame;
use super::error::HumanError;

/// f64 values per stored frame: 1 + 3 + 3 + 7 + 5·7 + 22.
pub const FRAME_WIDTH: usize = 71;

fn push_pose(out: &mut Vec<f64>, p: &Isometry3<f64>) {
    let v = p.translation.vector;
    let q = p.rotation.quaternion();
    out.extend_from_slice(&[v.x, v.y, v.z, q.w, q.i, q.j, q.k]);
}

fn read_pose(r: &[f64]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(r[0], r[1], r[2]),
        // Stored quaternions are unit up to rounding; renormalise rather than trust the bytes.
        UnitQuaternion::from_quaternion(Quaternion::new(r[3], r[4], r[5], r[6])),
    )
}

/// Flatten frames and their glove angles (same length) row-major.
pub fn pack_frames(frames: &[HumanFrame], glove: &[[f64; 22]]) -> Vec<f64> {
    assert_eq!(frames.len(), glove.len(), "one glove row per frame");
    let mut out = Vec::with_capacity(frames.len() * FRAME_WIDTH);
    for (f, g) in frames.iter().zip(glove) {
        out.push(f.t);
        out.extend_from_slice(f.shoulder.coords.as_slice());
        out.extend_from_slice(f.elbow.coords.as_slice());
        push_pose(&mut out, &f.wrist);
        for tip in &f.fingertips {
            push_pose(&mut out, tip);
        }
        out.extend_from_slice(g);
    }
    out
}

/// Inverse of [`pack_frames`].
pub fn unpack_frames(data: &[f64]) -> Result<(Vec<HumanFrame>, Vec<[f64; 22]>), HumanError> {
    if !data.len().is_multiple_of(FRAME_WIDTH) {
        return Err(HumanError::MalformedStorage {
            reason: format!("{} values is not a multiple of {FRAME_WIDTH}", data.len()),
        });
    }
    let n = data.len() / FRAME_WIDTH;
    let mut frames = Vec::with_capacity(n);
    let mut glove = Vec::with_capacity(n);
    for r in data.chunks_exact(FRAME_WIDTH) {
        frames.push(HumanFrame {
            t: r[0],
            shoulder: Point3::new(r[1], r[2], r[3]),
            elbow: Point3::new(r[4], r[5], r[6]),
            wrist: read_pose(&r[7..14]),
            fingertips: std::array::from_fn(|k| read_pose(&r[14 + 7 * k..21 + 7 * k])),
        });
        let mut g = [0.0; 22];
        g.copy_from_slice(&r[49..71]);
        glove.push(g);
    }
    Ok((frames, glove))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn frames_round_trip_through_the_flat_form() {
        let pose = |s: f64| {
            Isometry3::from_parts(
                Translation3::new(s, -s, 2.0 * s),
                UnitQuaternion::from_scaled_axis(Vector3::new(0.1 * s, 0.2, -0.3)),
            )
        };
        let frames: Vec<HumanFrame> = (0..3)
            .map(|k| {
                let s = k as f64 * 0.1;
                HumanFrame {
                    t: s,
                    shoulder: Point3::new(s, 1.0, 2.0),
                    elbow: Point3::new(0.5, s, 0.0),
                    wrist: pose(s),
                    fingertips: std::array::from_fn(|f| pose(s + f as f64)),
                }
            })
            .collect();
        let glove: Vec<[f64; 22]> = (0..3)
            .map(|k| std::array::from_fn(|c| (k * c) as f64))
            .collect();
        let flat = pack_frames(&frames, &glove);
        assert_eq!(flat.len(), 3 * FRAME_WIDTH);
        let (f2, g2) = unpack_frames(&flat).unwrap();
        assert_eq!(g2, glove);
        for (a, b) in frames.iter().zip(&f2) {
            assert_eq!(a.t, b.t);
            assert_eq!(a.shoulder, b.shoulder);
            assert!(a.wrist.rotation.angle_to(&b.wrist.rotation) < 1e-12);
            for (p, q) in a.fingertips.iter().zip(&b.fingertips) {
                assert!((p.translation.vector - q.translation.vector).norm() < 1e-15);
            }
        }
        assert!(unpack_frames(&flat[1..]).is_err());
    }
}
