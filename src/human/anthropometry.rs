//! Parametric anthropometry: segment lengths of the hand from hand length and breadth, and of the
//! arm from stature (paper §II-B: "parametric models derived from hand anthropometry studies").
//!
//! Sources:
//! * Hand: Buchholz B., Armstrong T. J., Goldstein S. A. (1992), "Anthropometric data for describing
//!   the kinematics of the human hand", Ergonomics 35(3):261-273 — segment lengths as fractions of
//!   hand length (wrist crease to the tip of the middle finger):
//!
//!   | finger | metacarpal | proximal | middle | distal |
//!   |--------|-----------:|---------:|-------:|-------:|
//!   | thumb  | 0.251      | 0.196    |   —    | 0.158  |
//!   | index  | 0.374      | 0.265    | 0.143  | 0.097  |
//!   | middle | 0.373      | 0.277    | 0.170  | 0.108  |
//!   | ring   | 0.336      | 0.259    | 0.165  | 0.107  |
//!   | little | 0.295      | 0.206    | 0.117  | 0.093  |
//!
//!   (For the thumb, "metacarpal" is CMC→MCP, "proximal" MCP→IP and "distal" IP→tip.)
//!   The lateral spacing of the MCP joints and the position of the thumb CMC joint are expressed
//!   as fractions of hand breadth (metacarpal breadth). These fractions are our own approximation
//!   of a typical joint-centre layout (about 2 cm between adjacent MCP heads for an average hand),
//!   not coefficients from the paper.
//! * Arm: Drillis R., Contini R. (1966), "Body segment parameters", report 1166-03, New York
//!   University, as reproduced in Winter D. A., "Biomechanics and Motor Control of Human
//!   Movement", 4th ed. (2009), fig. 4.1: upper arm 0.186 H, forearm 0.146 H, hand 0.108 H,
//!   shoulder width 0.259 H (H = stature).
//! * Average-adult defaults: stature 1.72 m, hand length 0.185 m, hand breadth 0.085 m — rounded
//!   midpoints of typical adult male and female means (e.g. Pheasant & Haslegrave, "Bodyspace",
//!   3rd ed., 2006); hand length ≈ 0.108 × stature agrees with Drillis & Contini.

use nalgebra::Vector3;

use super::error::HumanError;

/// Average adult stature, metres.
pub const DEFAULT_STATURE_M: f64 = 1.72;
/// Average adult hand length (wrist crease to middle fingertip), metres.
pub const DEFAULT_HAND_LENGTH_M: f64 = 0.185;
/// Average adult hand breadth (across the metacarpal heads), metres.
pub const DEFAULT_HAND_BREADTH_M: f64 = 0.085;

/// Buchholz et al. (1992): [metacarpal, proximal, middle, distal] × hand length for
/// thumb, index, middle, ring, little. The thumb has no middle phalanx (0.0).
pub const BUCHHOLZ_COEFFICIENTS: [[f64; 4]; 5] = [
    [0.251, 0.196, 0.0, 0.158],
    [0.374, 0.265, 0.143, 0.097],
    [0.373, 0.277, 0.170, 0.108],
    [0.336, 0.259, 0.165, 0.107],
    [0.295, 0.206, 0.117, 0.093],
];

/// Distance from the wrist joint centre to the carpometacarpal row, as a fraction of hand length:
/// the middle finger's chain (0.373 + 0.277 + 0.170 + 0.108 = 0.928) plus this carpal part spans
/// the hand length.
const CARPAL_FRACTION: f64 = 1.0 - 0.928;

/// Lateral (ulnar-positive, right hand) position of the MCP joints of index..little and of the
/// thumb CMC joint, × hand breadth. The middle finger's MCP defines the wrist frame's `x` axis.
const MCP_LATERAL: [f64; 5] = [-0.30, -0.26, 0.0, 0.24, 0.45];
/// Rest splay of each finger's chain about the palmar normal, radians (fingers converge towards
/// the scaphoid when flexed, so at rest they diverge by a few degrees; the thumb's metacarpal
/// points ~40° radially). Our approximation.
const FINGER_SPLAY: [f64; 5] = [-0.70, -0.10, 0.0, 0.08, 0.18];

/// Segment geometry of one finger, in the wrist frame of a right hand.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FingerDims {
    /// Position of the first joint of the chain (thumb: CMC; fingers: MCP), wrist frame, metres.
    pub base: Vector3<f64>,
    /// Rest direction of the chain in the palm plane: rotation about the palmar normal, radians.
    pub splay: f64,
    /// Thumb: [metacarpal, proximal, distal]; fingers: [proximal, middle, distal]. Metres.
    pub phalanges: [f64; 3],
}

/// The hand's segment lengths and joint locations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandDims {
    pub length: f64,
    pub breadth: f64,
    /// Thumb, index, middle, ring, little.
    pub fingers: [FingerDims; 5],
}

impl HandDims {
    /// Buchholz et al. (1992) parametric hand from hand length and breadth (metres).
    pub fn from_measurements(hand_length: f64, hand_breadth: f64) -> Result<Self, HumanError> {
        check_range("subject.hand_length_m", hand_length, 0.10, 0.30)?;
        check_range("subject.hand_breadth_m", hand_breadth, 0.04, 0.15)?;
        let hl = hand_length;
        let fingers = std::array::from_fn(|f| {
            let c = BUCHHOLZ_COEFFICIENTS[f];
            if f == 0 {
                // The thumb CMC sits on the radial side of the carpus, a little palmar.
                FingerDims {
                    base: Vector3::new(
                        CARPAL_FRACTION * hl + 0.02 * hl,
                        MCP_LATERAL[0] * hand_breadth,
                        0.08 * hand_breadth,
                    ),
                    splay: FINGER_SPLAY[0],
                    phalanges: [c[0] * hl, c[1] * hl, c[3] * hl],
                }
            } else {
                FingerDims {
                    base: Vector3::new(
                        (CARPAL_FRACTION + c[0]) * hl,
                        MCP_LATERAL[f] * hand_breadth,
                        0.0,
                    ),
                    splay: FINGER_SPLAY[f],
                    phalanges: [c[1] * hl, c[2] * hl, c[3] * hl],
                }
            }
        });
        Ok(Self {
            length: hand_length,
            breadth: hand_breadth,
            fingers,
        })
    }
}

impl Default for HandDims {
    fn default() -> Self {
        Self::from_measurements(DEFAULT_HAND_LENGTH_M, DEFAULT_HAND_BREADTH_M)
            .expect("defaults are in range")
    }
}

/// Arm segment lengths (Drillis & Contini 1966 via Winter 2009), metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmDims {
    pub stature: f64,
    /// Shoulder (glenohumeral centre) to elbow centre.
    pub upper_arm: f64,
    /// Elbow centre to wrist centre.
    pub forearm: f64,
    /// Wrist centre to the tip of the middle finger (used when no hand length is measured).
    pub hand: f64,
    /// Distance between the two shoulder joint centres.
    pub shoulder_width: f64,
}

impl ArmDims {
    pub fn from_stature(stature: f64) -> Result<Self, HumanError> {
        check_range("subject.stature_m", stature, 1.0, 2.3)?;
        Ok(Self {
            stature,
            upper_arm: 0.186 * stature,
            forearm: 0.146 * stature,
            hand: 0.108 * stature,
            shoulder_width: 0.259 * stature,
        })
    }

    /// Shoulder-to-wrist length with the elbow straight.
    pub fn reach(&self) -> f64 {
        self.upper_arm + self.forearm
    }
}

impl Default for ArmDims {
    fn default() -> Self {
        Self::from_stature(DEFAULT_STATURE_M).expect("default is in range")
    }
}

pub(crate) fn check_range(field: &str, value: f64, lo: f64, hi: f64) -> Result<(), HumanError> {
    if !value.is_finite() {
        return Err(HumanError::InvalidParameter {
            field: field.to_string(),
            value,
            reason: "not a finite number",
        });
    }
    if value < lo || value > hi {
        return Err(HumanError::InvalidParameter {
            field: field.to_string(),
            value,
            reason: "outside the plausible adult range",
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_phalanges_follow_buchholz() {
        let h = HandDims::from_measurements(0.2, 0.09).unwrap();
        let p = h.fingers[1].phalanges;
        assert!((p[0] - 0.265 * 0.2).abs() < 1e-12);
        assert!((p[1] - 0.143 * 0.2).abs() < 1e-12);
        assert!((p[2] - 0.097 * 0.2).abs() < 1e-12);
    }

    #[test]
    fn middle_finger_spans_the_hand_length() {
        let h = HandDims::default();
        let m = h.fingers[2];
        let total = m.base.x + m.phalanges.iter().sum::<f64>();
        assert!((total - h.length).abs() < 1e-12);
        assert_eq!(m.base.y, 0.0);
    }

    #[test]
    fn arm_segments_scale_with_stature() {
        let a = ArmDims::from_stature(1.8).unwrap();
        assert!((a.upper_arm - 0.186 * 1.8).abs() < 1e-12);
        assert!((a.forearm - 0.146 * 1.8).abs() < 1e-12);
    }

    #[test]
    fn implausible_measurements_are_rejected_naming_the_field() {
        let e = HandDims::from_measurements(0.02, 0.08).unwrap_err();
        assert_eq!(e.field(), Some("subject.hand_length_m"));
        let e = ArmDims::from_stature(f64::NAN).unwrap_err();
        assert_eq!(e.field(), Some("subject.stature_m"));
    }
}
