//! Seeded synthetic reach-to-grasp study (paper §II-D design: subjects × object positions ×
//! trials), emitting the two raw sensor streams so that it goes through the same ingest path as
//! recorded data.
//!
//! Motor-control model of one trial (normalised movement time `τ ∈ [0, 1]`):
//! * Wrist transport: minimum jerk `s(τ) = 10τ³ − 15τ⁴ + 6τ⁵` from the resting hand to the grasp
//!   pose (Flash & Hogan 1985), plus a small lift `h · 64 τ³(1−τ)³` off the table. Speed is
//!   single-peaked (bell-shaped). Movement time grows with distance (Fitts-like).
//! * Wrist orientation: slerp from the resting orientation to the grasp orientation, finishing
//!   slightly before the transport does.
//! * Elbow: on the circle allowed by the upper-arm and forearm lengths around the shoulder–wrist
//!   axis, at a swivel angle measured from the lowest point of that circle, outward positive,
//!   moving by minimum jerk from a low resting swivel to a moderately raised one (Kang et al.
//!   2005 describe the natural swivel as the elbow hanging low and slightly out).
//! * Hand: preshaping opens the hand by minimum jerk until `τ_peak ∈ [0.6, 0.8]`, to a maximum grip
//!   aperture (thumb tip to index tip) of `0.8 · size + 0.05 m` (the linear scaling reported by
//!   Jeannerod 1984 and Smeets & Brenner 1999), then closes onto the object: each finger flexes
//!   along its own closing synergy until its tip reaches the object surface.
//! * Variability: movement time, lift, swivel, peak timing, aperture and final wrist pose vary
//!   from trial to trial; sensor noise at the stated accuracies (Liberty: 0.03 in, 0.15°;
//!   CyberGlove II: 1°) is added as zero-mean Gaussian noise with σ = half the stated accuracy.
//!
//! Scene (tracker frame): origin on the table edge in front of the subject's right shoulder, `x`
//! forward, `y` left, `z` up. The shoulder is 0.15 m behind the edge at 0.19 × stature above the
//! table (a seated subject at a standard table). The five object positions lie on an arc in
//! front of the shoulder at 62-80 % of the subject's arm length, from 35° left to 35° right.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::anthropometry::HandDims;
use super::demo::{
    DemonstrationInput, GloveStream, Handedness, Labels, ObjectShape, ObjectSpec, Pose, Subject,
    SyncOptions, TrackerStream,
};
use super::derive::HandKinematics;
use super::error::HumanError;
use super::model::{HAND_DOF, hand_spec};

/// The everyday objects of the study, as simple shapes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    Ball,
    Bottle,
    KitchenTimer,
    Pencil,
    Sunglasses,
}

/// How the hand takes an object.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Style {
    /// Palm down from above, palm on (or just above) the object; fingers wrap down.
    TopPower,
    /// From the side, palm against the object, fingers wrapping around it.
    LateralPower,
    /// From above with thumb and index pads (other fingers curl).
    TopPinch,
}

impl ObjectKind {
    pub const ALL: [ObjectKind; 5] = [
        Self::Ball,
        Self::Bottle,
        Self::KitchenTimer,
        Self::Pencil,
        Self::Sunglasses,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            Self::Ball => "ball",
            Self::Bottle => "bottle",
            Self::KitchenTimer => "kitchen_timer",
            Self::Pencil => "pencil",
            Self::Sunglasses => "sunglasses",
        }
    }

    /// Shape with typical dimensions (tennis-ball-sized ball, 0.5 l bottle, round dial timer,
    /// pencil, folded sunglasses).
    pub fn shape(&self) -> ObjectShape {
        match self {
            Self::Ball => ObjectShape::Sphere { radius: 0.04 },
            Self::Bottle => ObjectShape::Cylinder {
                radius: 0.033,
                height: 0.21,
            },
            Self::KitchenTimer => ObjectShape::Cylinder {
                radius: 0.03,
                height: 0.055,
            },
            Self::Pencil => ObjectShape::Cylinder {
                radius: 0.0035,
                height: 0.17,
            },
            Self::Sunglasses => ObjectShape::Box {
                size: [0.145, 0.05, 0.04],
            },
        }
    }

    /// The object's extent that the grip spans (drives the maximum grip aperture).
    pub fn grasp_size(&self) -> f64 {
        match self {
            Self::Ball => 0.08,
            Self::Bottle => 0.066,
            Self::KitchenTimer => 0.06,
            Self::Pencil => 0.007,
            Self::Sunglasses => 0.05,
        }
    }

    fn style(&self) -> Style {
        match self {
            Self::Ball | Self::KitchenTimer | Self::Sunglasses => Style::TopPower,
            Self::Bottle => Style::LateralPower,
            Self::Pencil => Style::TopPinch,
        }
    }

    /// Object pose on the table at horizontal position `xy`, seen from the shoulder along the
    /// horizontal approach direction `a`.
    fn pose(&self, xy: [f64; 2], a: &Vector3<f64>) -> Isometry3<f64> {
        let yaw = a.y.atan2(a.x);
        let (z, rot) = match self {
            // The ball sits on a small ring stand.
            Self::Ball => (0.05, UnitQuaternion::identity()),
            Self::Bottle => (0.105, UnitQuaternion::identity()),
            Self::KitchenTimer => (0.0275, UnitQuaternion::identity()),
            // Lying across the approach direction: cylinder axis (z) horizontal.
            Self::Pencil => (
                0.0035,
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw)
                    * UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f64::consts::FRAC_PI_2,
                    ),
            ),
            // Long side across the approach direction, lying flat.
            Self::Sunglasses => (
                0.02,
                UnitQuaternion::from_axis_angle(
                    &Vector3::z_axis(),
                    yaw + std::f64::consts::FRAC_PI_2,
                ),
            ),
        };
        Isometry3::from_parts(Translation3::new(xy[0], xy[1], z), rot)
    }
}

/// The study design. Defaults reproduce the paper's: 5 subjects, 5 positions, 10 trials, and the
/// five objects counterbalanced over positions (subject `s` meets object `(p + s) mod 5` at
/// position `p`), 250 demonstrations; `full_factorial` crosses every object with every position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StudyConfig {
    pub seed: u64,
    pub subjects: usize,
    pub positions: usize,
    pub trials: usize,
    pub objects: Vec<ObjectKind>,
    pub full_factorial: bool,
    /// Add sensor noise at the devices' stated accuracy.
    pub noise: bool,
    /// Common output rate for ingest, Hz.
    pub rate_hz: f64,
}

impl Default for StudyConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            subjects: 5,
            positions: 5,
            trials: 10,
            objects: ObjectKind::ALL.to_vec(),
            full_factorial: false,
            noise: true,
            rate_hz: 120.0,
        }
    }
}

/// One trial of the study.
#[derive(Debug, Clone, PartialEq)]
pub struct TrialSpec {
    pub subject: Subject,
    pub subject_index: usize,
    pub object: ObjectKind,
    pub position_index: usize,
    pub trial: usize,
    pub noise: bool,
    pub rate_hz: f64,
}

/// Limits on a study request (keeps a job bounded).
pub const MAX_SUBJECTS: usize = 50;
pub const MAX_TRIALS: usize = 100;
pub const MAX_DEMONSTRATIONS: usize = 5000;
/// Number of distinct object positions of the scene.
pub const POSITIONS: usize = 5;

const POSITION_AZIMUTH_DEG: [f64; POSITIONS] = [35.0, 15.0, 0.0, -15.0, -35.0];
const POSITION_REACH: [f64; POSITIONS] = [0.62, 0.72, 0.80, 0.72, 0.62];
const TRACKER_HZ: f64 = 240.0;
const GLOVE_HZ: f64 = 90.0;
/// Liberty accuracy: 0.03 in and 0.15°; CyberGlove II: 1°. σ = half the stated accuracy.
const TRACKER_POS_SIGMA: f64 = 0.5 * 0.03 * 0.0254;
const TRACKER_ROT_SIGMA: f64 = 0.5 * 0.15 * std::f64::consts::PI / 180.0;
const GLOVE_SIGMA: f64 = 0.5 * std::f64::consts::PI / 180.0;

impl StudyConfig {
    pub fn validate(&self) -> Result<(), HumanError> {
        // Not `check_range`: its message speaks of adult body measurements.
        let allowed = |field: &str, value: f64, lo: f64, hi: f64| {
            if (lo..=hi).contains(&value) {
                Ok(())
            } else {
                Err(HumanError::InvalidParameter {
                    field: field.into(),
                    value,
                    reason: "outside the range a study allows",
                })
            }
        };
        let count = |field: &str, v: usize, max: usize| allowed(field, v as f64, 1.0, max as f64);
        count("subjects", self.subjects, MAX_SUBJECTS)?;
        count("positions", self.positions, POSITIONS)?;
        count("trials", self.trials, MAX_TRIALS)?;
        count("objects", self.objects.len(), ObjectKind::ALL.len())?;
        allowed("rate_hz", self.rate_hz, 1.0, 1000.0)?;
        let n = self.len();
        if n > MAX_DEMONSTRATIONS {
            return Err(HumanError::InvalidParameter {
                field: "trials".into(),
                value: n as f64,
                reason: "the study would exceed 5000 demonstrations",
            });
        }
        Ok(())
    }

    /// Number of demonstrations the study produces.
    pub fn len(&self) -> usize {
        let per = if self.full_factorial {
            self.objects.len()
        } else {
            1
        };
        self.subjects * self.positions * per * self.trials
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The study's subjects: statures spread over the adult range, hand size in proportion with
    /// individual variation (Drillis & Contini: hand length ≈ 0.108 × stature; hand breadth ≈ 0.46
    /// × hand length).
    pub fn study_subjects(&self) -> Vec<Subject> {
        const STATURES: [f64; 5] = [1.62, 1.80, 1.70, 1.86, 1.66];
        (0..self.subjects)
            .map(|i| {
                let mut rng = rng_for(self.seed, &[0x5B, i as u64]);
                let stature = STATURES[i % 5] + 0.02 * gauss(&mut rng);
                let hand_length = 0.108 * stature * (1.0 + 0.03 * gauss(&mut rng));
                let hand_breadth = 0.46 * hand_length * (1.0 + 0.04 * gauss(&mut rng));
                Subject {
                    id: format!("S{}", i + 1),
                    stature_m: round_to(stature, 1e-3),
                    hand_length_m: round_to(hand_length, 1e-4),
                    hand_breadth_m: round_to(hand_breadth, 1e-4),
                    handedness: Handedness::Right,
                }
            })
            .collect()
    }

    /// Every trial of the study, in a fixed order.
    pub fn trials(&self) -> Vec<TrialSpec> {
        let subjects = self.study_subjects();
        let mut out = Vec::with_capacity(self.len());
        for (s, subject) in subjects.iter().enumerate() {
            for p in 0..self.positions {
                let objects: Vec<ObjectKind> = if self.full_factorial {
                    self.objects.clone()
                } else {
                    vec![self.objects[(p + s) % self.objects.len()]]
                };
                for object in objects {
                    for k in 0..self.trials {
                        out.push(TrialSpec {
                            subject: subject.clone(),
                            subject_index: s,
                            object,
                            position_index: p,
                            trial: k,
                            noise: self.noise,
                            rate_hz: self.rate_hz,
                        });
                    }
                }
            }
        }
        out
    }
}

/// Generate the whole study (raw sensor streams, labelled synthetic).
pub fn generate_study(cfg: &StudyConfig) -> Result<Vec<DemonstrationInput>, HumanError> {
    generate_study_with_progress(cfg, &mut |_, _| {})
}

/// [`generate_study`], calling `progress(done, total)` after each trial.
pub fn generate_study_with_progress(
    cfg: &StudyConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<DemonstrationInput>, HumanError> {
    cfg.validate()?;
    let trials = cfg.trials();
    let mut out = Vec::with_capacity(trials.len());
    let mut hands: Vec<Option<HandKinematics>> = vec![None; cfg.subjects];
    for spec in &trials {
        let hk = match &mut hands[spec.subject_index] {
            Some(h) => h,
            slot @ None => slot.insert(HandKinematics::new(
                &spec.subject.hand_dims()?,
                spec.subject.handedness,
            )),
        };
        out.push(generate_trial_with(spec, cfg.seed, hk)?);
        progress(out.len(), trials.len());
    }
    Ok(out)
}

/// Generate one trial (deterministic for `(seed, subject, object, position, trial)`).
pub fn generate_trial(spec: &TrialSpec, seed: u64) -> Result<DemonstrationInput, HumanError> {
    let mut hk = HandKinematics::new(&spec.subject.hand_dims()?, spec.subject.handedness);
    generate_trial_with(spec, seed, &mut hk)
}

/// Minimum-jerk position profile.
pub fn min_jerk(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * t * (10.0 + t * (-15.0 + 6.0 * t))
}

fn rng_for(seed: u64, parts: &[u64]) -> ChaCha8Rng {
    // SplitMix64 finaliser folds the trial's identity into one well-mixed seed, so that every
    // trial is reproducible on its own, independently of which other trials are generated.
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for &p in parts {
        h = (h ^ p).wrapping_add(0x9E37_79B9_7F4A_7C15);
        h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        h ^= h >> 31;
    }
    ChaCha8Rng::seed_from_u64(h)
}

/// Standard normal deviate (Box–Muller). Hand-rolled because `rand` 0.10 has no normal
/// distribution and one formula does not justify another crate.
fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn round_to(v: f64, q: f64) -> f64 {
    (v / q).round() * q
}

fn deg(v: f64) -> f64 {
    v.to_radians()
}

/// Hand postures (glove order, radians) used by the generator.
struct Postures {
    rest: [f64; HAND_DOF],
    open: [f64; HAND_DOF],
    closed: [f64; HAND_DOF],
    lower: [f64; HAND_DOF],
    upper: [f64; HAND_DOF],
}

fn postures(style: Style, dims: &HandDims) -> Postures {
    // Per finger: [abduction, mcp, pip, dip]; thumb: [abduction, opposition, mcp, ip]. Degrees.
    // Relaxed hand: thumb resting in front of the index, fingers curled (aperture ≈ 4 cm).
    let rest_thumb = [30.0, 40.0, 20.0, 20.0];
    let rest_f = [0.0, 30.0, 45.0, 20.0];
    let open_thumb = [55.0, 25.0, 0.0, -5.0];
    let open_abd = [12.0, 2.0, 8.0, 15.0];
    let open_f = [-10.0, 5.0, 0.0];
    let (closed_thumb, closed_f): ([f64; 4], [[f64; 3]; 4]) = match style {
        Style::TopPower | Style::LateralPower => {
            ([60.0, 35.0, 35.0, 40.0], [[85.0, 105.0, 70.0]; 4])
        }
        Style::TopPinch => (
            [40.0, 55.0, 35.0, 30.0],
            [
                [60.0, 55.0, 25.0],
                [65.0, 75.0, 40.0],
                [80.0, 100.0, 60.0],
                [85.0, 105.0, 65.0],
            ],
        ),
    };
    let mut p = Postures {
        rest: [0.0; HAND_DOF],
        open: [0.0; HAND_DOF],
        closed: [0.0; HAND_DOF],
        lower: [0.0; HAND_DOF],
        upper: [0.0; HAND_DOF],
    };
    for k in 0..4 {
        p.rest[k] = deg(rest_thumb[k]);
        p.open[k] = deg(open_thumb[k]);
        p.closed[k] = deg(closed_thumb[k]);
    }
    for f in 0..4 {
        let b = 4 + 4 * f;
        p.rest[b] = deg(rest_f[0]);
        p.open[b] = deg(open_abd[f]);
        p.closed[b] = deg(open_abd[f] * 0.3);
        for k in 0..3 {
            p.rest[b + 1 + k] = deg(rest_f[1 + k]);
            p.open[b + 1 + k] = deg(open_f[k]);
            p.closed[b + 1 + k] = deg(closed_f[f][k]);
        }
    }
    for (k, j) in hand_spec(dims, Handedness::Right)
        .iter()
        .filter(|j| j.axis.is_some())
        .enumerate()
    {
        p.lower[k] = j.lower;
        p.upper[k] = j.upper;
    }
    p
}

fn blend(a: &[f64; HAND_DOF], b: &[f64; HAND_DOF], s: f64) -> [f64; HAND_DOF] {
    std::array::from_fn(|k| a[k] + s * (b[k] - a[k]))
}

/// Indices of a finger's DoF in glove order.
fn finger_dofs(f: usize) -> std::ops::Range<usize> {
    if f == 0 { 0..4 } else { 4 * f..4 * f + 4 }
}

fn aperture(hk: &mut HandKinematics, q: &[f64; HAND_DOF]) -> f64 {
    let tips = hk.fingertips_local(q);
    (tips[0].translation.vector - tips[1].translation.vector).norm()
}

/// Grasp posture and placement: the wrist pose in the world and the final hand angles.
struct Grasp {
    wrist: Isometry3<f64>,
    q: [f64; HAND_DOF],
}

/// Hand orientation for a style, for horizontal approach direction `a` (unit, z = 0).
fn grasp_rotation(style: Style, a: &Vector3<f64>) -> UnitQuaternion<f64> {
    let up = Vector3::z();
    let left = up.cross(a);
    let (x, z) = match style {
        Style::TopPower | Style::TopPinch => {
            // Palm down, fingers forward and tilted 20° down.
            let x = (a * deg(20.0).cos() - up * deg(20.0).sin()).normalize();
            let y = -left;
            (x, x.cross(&y))
        }
        Style::LateralPower => {
            // Palm facing left-forward (10° from the pure lateral), thumb up, fingers forward-right.
            let z = (left * deg(10.0).cos() + a * deg(10.0).sin()).normalize();
            (z.cross(&up), z)
        }
    };
    let y = z.cross(&x);
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(
        &[x, y, z],
    )))
}

/// Place the hand on the object and close each finger onto its surface.
#[allow(clippy::too_many_arguments)]
fn solve_grasp(
    hk: &mut HandKinematics,
    dims: &HandDims,
    style: Style,
    postures: &Postures,
    open: &[f64; HAND_DOF],
    object: &ObjectSpec,
    rotation: UnitQuaternion<f64>,
    grasp_point: Vector3<f64>,
) -> Grasp {
    // Object centre in the wrist frame where the grasp holds it.
    let centre_in_hand = match style {
        Style::TopPower | Style::LateralPower => {
            let standoff = match object.shape {
                ObjectShape::Cylinder { height, .. } if style == Style::TopPower => {
                    0.5 * height + 0.01
                }
                ObjectShape::Box { size } if style == Style::TopPower => 0.5 * size[2] + 0.01,
                shape => 0.5 * shape.grasp_width() + 0.004,
            };
            // Palm centre: between the wrist and the MCP row, on the palmar skin.
            Vector3::new(0.30 * dims.length, 0.1 * dims.breadth, 0.015 + standoff)
        }
        Style::TopPinch => {
            // Where thumb and index pads meet when both close together.
            let mut best = (f64::INFINITY, Vector3::zeros());
            for k in 0..=40 {
                let s = k as f64 / 40.0;
                let q = blend(open, &postures.closed, s);
                let tips = hk.fingertips_local(&q);
                let (t, i) = (tips[0].translation.vector, tips[1].translation.vector);
                let d = (t - i).norm();
                if d < best.0 {
                    best = (d, 0.5 * (t + i));
                }
            }
            best.1
        }
    };
    let world_centre = object.pose.to_isometry() * Point3::from(grasp_point);
    let wrist_t = world_centre.coords - rotation * centre_in_hand;
    let mut wrist = Isometry3::from_parts(Translation3::from(wrist_t), rotation);
    let object_pose = object.pose.to_isometry();
    let mut q = *open;
    // A thumb that cannot reach the object (or that the open hand already pushes into it) means
    // the hand sits too far to one side: slide the hand along the surface normal at the thumb
    // tip by the thumb's signed gap and close again.
    for _ in 0..4 {
        let to_object = object_pose.inverse() * wrist;
        let (qh, thumb_gap) = close_hand(hk, object, &to_object, open, &postures.closed);
        q = qh;
        if thumb_gap.abs() < 1e-3 {
            break;
        }
        let tip = to_object * Point3::from(hk.fingertips_local(&q)[0].translation.vector);
        let h = 1e-6;
        let grad = Vector3::from_fn(|k, _| {
            let mut e = Vector3::zeros();
            e[k] = h;
            (object.shape.signed_distance(&(tip.coords + e))
                - object.shape.signed_distance(&(tip.coords - e)))
                / (2.0 * h)
        });
        if grad.norm() < 1e-9 {
            break;
        }
        // Moving the hand by +δ moves the object by −δ relative to the thumb tip.
        let shift = object_pose.rotation * (-grad.normalize() * thumb_gap);
        wrist.translation.vector += shift;
    }
    Grasp { wrist, q }
}

/// Close the fingers and then the thumb onto the object (hand placed at `to_object` relative to
/// the object frame). Fingers close along their synergy; the thumb tries a few closing targets
/// (more or less opposition) and keeps the one that touches the object farthest from the index
/// pad — the opposing contact a real grasp would use. Returns the posture and the thumb's
/// signed gap to the surface (negative: inside).
fn close_hand(
    hk: &mut HandKinematics,
    object: &ObjectSpec,
    to_object: &Isometry3<f64>,
    open: &[f64; HAND_DOF],
    closed: &[f64; HAND_DOF],
) -> ([f64; HAND_DOF], f64) {
    let mut q = *open;
    for f in 1..5 {
        q = close_finger(hk, object, to_object, &q, open, closed, f).0;
    }
    let index_tip = hk.fingertips_local(&q)[1].translation.vector;
    let mut best: Option<(bool, f64, f64, [f64; HAND_DOF])> = None;
    for abd in [45.0, 60.0] {
        for opp in [20.0, 35.0, 50.0, 65.0, 80.0] {
            let mut target = *closed;
            target[0] = deg(abd);
            target[1] = deg(opp);
            let (qt, gap) = close_finger(hk, object, to_object, &q, open, &target, 0);
            let touching = gap.abs() < 1e-3;
            let spread = (hk.fingertips_local(&qt)[0].translation.vector - index_tip).norm();
            // Prefer touching, then the widest opposition; among misses, the smallest gap.
            let key = if touching { spread } else { -gap.abs() };
            let better = match &best {
                None => true,
                Some((bt, bk, _, _)) => (touching, key) > (*bt, *bk),
            };
            if better {
                best = Some((touching, key, gap, qt));
            }
        }
    }
    let (_, _, gap, qt) = best.expect("candidates were tried");
    (qt, gap)
}

/// Close finger `f` of `q` from `open` towards `closed` until its pad touches the surface (pad
/// contact at ~4 mm from the tip's centre line). Returns the posture and the remaining pad
/// distance (0 at contact; positive when the finger closed fully without touching). A tip that
/// starts inside the object (the open hand already overlaps it) is opened further until it is
/// outside, so that the pad rests on the surface.
fn close_finger(
    hk: &mut HandKinematics,
    object: &ObjectSpec,
    to_object: &Isometry3<f64>,
    q: &[f64; HAND_DOF],
    open: &[f64; HAND_DOF],
    closed: &[f64; HAND_DOF],
    f: usize,
) -> ([f64; HAND_DOF], f64) {
    const PAD: f64 = 0.004;
    const STEPS: usize = 24;
    let dofs = finger_dofs(f);
    let mut dist = |s: f64| {
        let mut qq = *q;
        for k in dofs.clone() {
            qq[k] = open[k] + s * (closed[k] - open[k]);
        }
        let tip = hk.fingertips_local(&qq)[f];
        let d = object
            .shape
            .signed_distance(&(to_object * Point3::from(tip.translation.vector)).coords)
            - PAD;
        (qq, d)
    };
    let mut bracket = None;
    if dist(0.0).1 <= 0.0 {
        for k in 1..=STEPS {
            let s = -(k as f64) / STEPS as f64;
            if dist(s).1 > 0.0 {
                bracket = Some((s, s + 1.0 / STEPS as f64));
                break;
            }
        }
    } else {
        for k in 1..=STEPS {
            let s = k as f64 / STEPS as f64;
            if dist(s).1 <= 0.0 {
                bracket = Some((s - 1.0 / STEPS as f64, s));
                break;
            }
        }
    }
    match bracket {
        Some((mut lo, mut hi)) => {
            for _ in 0..30 {
                let mid = 0.5 * (lo + hi);
                if dist(mid).1 <= 0.0 {
                    hi = mid
                } else {
                    lo = mid
                }
            }
            dist(lo)
        }
        None => dist(1.0),
    }
}

fn clamp_q(q: &mut [f64; HAND_DOF], p: &Postures) {
    for (k, v) in q.iter_mut().enumerate() {
        *v = v.clamp(p.lower[k], p.upper[k]);
    }
}

/// Elbow on the swivel circle (see the module documentation).
fn elbow_position(
    shoulder: &Vector3<f64>,
    wrist: &Vector3<f64>,
    upper: f64,
    fore: f64,
    swivel: f64,
) -> Vector3<f64> {
    let sw = wrist - shoulder;
    let d = sw.norm();
    let n = sw / d;
    let a = (upper * upper - fore * fore + d * d) / (2.0 * d);
    let r = (upper * upper - a * a).max(0.0).sqrt();
    let down = -Vector3::z();
    let u = (down - n * n.dot(&down)).normalize();
    let v = u.cross(&n); // lateral (to the right) for a right arm
    shoulder + n * a + (u * swivel.cos() + v * swivel.sin()) * r
}

fn generate_trial_with(
    spec: &TrialSpec,
    seed: u64,
    hk: &mut HandKinematics,
) -> Result<DemonstrationInput, HumanError> {
    let subject = &spec.subject;
    let arm = subject.arm_dims()?;
    let dims = subject.hand_dims()?;
    let object_index = ObjectKind::ALL
        .iter()
        .position(|o| *o == spec.object)
        .unwrap_or(0);
    let mut rng = rng_for(
        seed,
        &[
            spec.subject_index as u64,
            spec.position_index as u64,
            object_index as u64,
            spec.trial as u64,
        ],
    );
    let mut g = || gauss(&mut rng);

    // Scene.
    let shoulder0 = Vector3::new(-0.15, 0.0, 0.19 * arm.stature);
    let reach = arm.reach();
    let p = spec.position_index % POSITIONS;
    let az = deg(POSITION_AZIMUTH_DEG[p]);
    let rho = POSITION_REACH[p] * reach;
    let xy = [shoulder0.x + rho * az.cos(), shoulder0.y + rho * az.sin()];
    let a = Vector3::new(az.cos(), az.sin(), 0.0);
    let style = spec.object.style();
    let object = ObjectSpec {
        name: spec.object.name().to_string(),
        shape: spec.object.shape(),
        pose: Pose::from_isometry(&spec.object.pose(xy, &a)),
    };
    // Bottles are held low, below their centre.
    let grasp_point = match spec.object {
        ObjectKind::Bottle => Vector3::new(0.0, 0.0, -0.025),
        _ => Vector3::zeros(),
    };

    // Trial variability.
    let duration = (0.75 + 0.9 * rho) * (1.0 + 0.06 * g());
    let lift = (0.035 + 0.008 * g()).clamp(0.015, 0.06);
    let t_peak = (0.70 + 0.035 * g()).clamp(0.61, 0.79);
    let mga_target = (0.8 * spec.object.grasp_size() + 0.05) * (1.0 + 0.04 * g());
    let swivel0 = deg(12.0 + 4.0 * g());
    let swivel1 = deg(28.0 + 6.0 * g());
    let lean = 0.015 + 0.005 * g();
    let rest_before = 0.3 + 0.05 * g().abs();
    let hold_after = 0.3 + 0.05 * g().abs();
    let end_jitter = Vector3::new(g(), g(), g()) * 0.003;
    let rot_jitter = UnitQuaternion::from_scaled_axis(Vector3::new(g(), g(), g()) * deg(2.0));
    let start_xy = [
        shoulder0.x + 0.22 * reach + 0.01 * g(),
        shoulder0.y - 0.03 + 0.01 * g(),
    ];

    // Hand postures: preshape opening matched to the aperture target.
    let post = postures(style, &dims);
    let mut q_rest = post.rest;
    clamp_q(&mut q_rest, &post);
    let (mut lo, mut hi) = (0.0, 1.0);
    let max_open = blend(&post.rest, &post.open, 1.0);
    let q_open = if aperture(hk, &max_open) <= mga_target {
        max_open
    } else {
        for _ in 0..30 {
            let mid = 0.5 * (lo + hi);
            if aperture(hk, &blend(&post.rest, &post.open, mid)) < mga_target {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        blend(&post.rest, &post.open, hi)
    };

    // The hand is yawed to line up with the forearm (as people do, keeping the wrist near
    // neutral deviation): place it once along the shoulder's approach direction, find where the
    // forearm then points, and place it again along that direction.
    let shoulder1 = shoulder0 + a * lean;
    let mut approach = a;
    let mut grasp = None;
    for _ in 0..2 {
        let rotation = rot_jitter * grasp_rotation(style, &approach);
        let g = solve_grasp(
            hk,
            &dims,
            style,
            &post,
            &q_open,
            &object,
            rotation,
            grasp_point + end_jitter,
        );
        let w = g.wrist.translation.vector;
        let e = elbow_position(&shoulder1, &w, arm.upper_arm, arm.forearm, swivel1);
        let f = Vector3::new(w.x - e.x, w.y - e.y, 0.0);
        if f.norm() > 1e-6 {
            approach = f.normalize();
        }
        grasp = Some(g);
    }
    let mut grasp = grasp.expect("two passes");
    clamp_q(&mut grasp.q, &post);

    // Resting hand: palm down on the table in line with the resting forearm, the wrist high
    // enough for the curled fingertips to rest on the table.
    let wrist0 = Vector3::new(start_xy[0], start_xy[1], 0.075);
    let e0 = elbow_position(&shoulder0, &wrist0, arm.upper_arm, arm.forearm, swivel0);
    let rest_x = Vector3::new(wrist0.x - e0.x, wrist0.y - e0.y, 0.0).normalize();
    let rest_z = -Vector3::z();
    let rest_rot = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(
        Matrix3::from_columns(&[rest_x, rest_z.cross(&rest_x), rest_z]),
    ));
    let wrist1 = grasp.wrist.translation.vector;
    let rot1 = grasp.wrist.rotation;

    // Reachability: the end of the transport is its farthest point from the shoulder.
    let dist = (wrist1 - shoulder1).norm();
    if dist > 0.97 * reach {
        return Err(HumanError::Unreachable {
            subject: subject.id.clone(),
            position: p,
            distance: dist,
            reach,
        });
    }

    let total = rest_before + duration + hold_after;
    let state = |t: f64| {
        let tau = ((t - rest_before) / duration).clamp(0.0, 1.0);
        let s = min_jerk(tau);
        let shoulder = shoulder0 + a * (lean * s);
        let bump = 64.0 * tau.powi(3) * (1.0 - tau).powi(3);
        let wrist = wrist0 + (wrist1 - wrist0) * s + Vector3::z() * (lift * bump);
        let rot = super::resample::slerp(&rest_rot, &rot1, min_jerk(tau / 0.9));
        let swivel = swivel0 + (swivel1 - swivel0) * s;
        let elbow = elbow_position(&shoulder, &wrist, arm.upper_arm, arm.forearm, swivel);
        let q = if tau <= t_peak {
            blend(&q_rest, &q_open, min_jerk(tau / t_peak))
        } else {
            blend(&q_open, &grasp.q, min_jerk((tau - t_peak) / (1.0 - t_peak)))
        };
        (
            shoulder,
            elbow,
            Isometry3::from_parts(Translation3::from(wrist), rot),
            q,
        )
    };

    // Tracker stream at 240 Hz.
    let nt = (total * TRACKER_HZ).floor() as usize + 1;
    let mut tracker = TrackerStream {
        t: Vec::with_capacity(nt),
        shoulder: Vec::with_capacity(nt),
        elbow: Vec::with_capacity(nt),
        wrist: Vec::with_capacity(nt),
        wrist_orientation: Vec::with_capacity(nt),
    };
    let noise = spec.noise;
    let mut g3 = |sigma: f64| {
        if noise {
            Vector3::new(g(), g(), g()) * sigma
        } else {
            Vector3::zeros()
        }
    };
    for k in 0..nt {
        let t = k as f64 / TRACKER_HZ;
        let (s, e, w, _) = state(t);
        let rq = UnitQuaternion::from_scaled_axis(g3(TRACKER_ROT_SIGMA)) * w.rotation;
        let q = rq.quaternion();
        let pos = |v: Vector3<f64>, n: Vector3<f64>| {
            let v = v + n;
            vec![v.x, v.y, v.z]
        };
        tracker.t.push(t);
        tracker.shoulder.push(pos(s, g3(TRACKER_POS_SIGMA)));
        tracker.elbow.push(pos(e, g3(TRACKER_POS_SIGMA)));
        tracker
            .wrist
            .push(pos(w.translation.vector, g3(TRACKER_POS_SIGMA)));
        tracker.wrist_orientation.push(vec![q.w, q.i, q.j, q.k]);
    }

    // Glove stream at 90 Hz, its first sample at a random phase of the tracker clock.
    let mut rng2 = rng_for(
        seed ^ 0x61_6C_6F_76_65,
        &[
            spec.subject_index as u64,
            p as u64,
            object_index as u64,
            spec.trial as u64,
        ],
    );
    let g0 = rng2.random::<f64>() / GLOVE_HZ;
    let ng = ((total - g0) * GLOVE_HZ).floor() as usize + 1;
    let mut glove_t = Vec::with_capacity(ng);
    let mut angles = Vec::with_capacity(ng);
    for k in 0..ng {
        let t = g0 + k as f64 / GLOVE_HZ;
        glove_t.push(t);
        let (_, e, w, q) = state(t);
        // Wrist channels: the hand's tilt relative to the forearm axis, in the hand frame.
        let f = w.rotation.inverse() * (w.translation.vector - e).normalize();
        let flex = (-f.z).atan2(f.x);
        let dev = (-f.y).atan2(f.x);
        let mut row = Vec::with_capacity(22);
        row.extend_from_slice(&q);
        row.push(flex);
        row.push(dev);
        if noise {
            row.iter_mut()
                .for_each(|v| *v += GLOVE_SIGMA * gauss(&mut rng2));
        }
        angles.push(row);
    }

    Ok(DemonstrationInput {
        subject: subject.clone(),
        object,
        labels: Labels {
            task: "grasp".into(),
            position_index: p as u32,
            trial: spec.trial as u32,
            synthetic: true,
            external_id: Some(format!(
                "synth-{seed}-{}-{}-p{p}-t{}",
                subject.id,
                spec.object.name(),
                spec.trial
            )),
        },
        tracker,
        glove: GloveStream {
            t: glove_t,
            angles: Some(angles),
            raw: None,
            calibration: None,
        },
        keypoints: None,
        sync: SyncOptions {
            rate_hz: spec.rate_hz,
            ..SyncOptions::default()
        },
    })
}
