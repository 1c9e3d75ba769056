//! Online retargeting (issue 22): one keypoint frame in, the robot's joint values out, frame by
//! frame, with the mapping objective of eq. 1-7 (arm and hand together, the elbow and swivel
//! terms where the system has an arm).
//!
//! - **First frame**: the mapping's multi-start ([`Mapper::solve_first`]), so a stream starts on
//!   the best posture branch instead of wherever a single local solve lands; later frames are
//!   warm-started from the previous solution inside the per-frame step box
//!   ([`Mapper::solve_next`]). The solver never sees the filtered output, so filtering adds no lag
//!   to the solution it warm-starts from.
//! - **Registration**: a hand on a fixed base registers every frame relative to the subject's
//!   wrist (no arm needed). An arm system needs the elbow and shoulder in every frame; its
//!   registration is resolved once, on the first frame (the scene registration of
//!   [`super::registration`] without an object: the first wrist lands at `placement`, or where
//!   the scaled human reach puts it above the robot's support), and kept for the stream, so the
//!   robot follows the subject's motion rather than re-anchoring every frame. The transport scale
//!   is robot reach / human reach with the human reach from the subject's stature
//!   ([`crate::human::ArmDims`]): a single frame's bent arm would give a wrong ratio.
//! - **Output**: an optional first-order low-pass (`cutoff_hz`, exact discretisation
//!   `α = 1 − exp(−2π f_c Δt)` for any frame spacing) and an optional speed bound (`speed_scale`
//!   times each joint's URDF velocity limit, per frame `Δt`), applied in that order.
//!
//! Pure computation: no I/O, and after the first frame no allocation per frame.

use nalgebra::Point3;

use super::objective::{FrameGoals, MappingModel, Weights};
use super::registration::{RegistrationSpec, RobotAnchor, Scale, SceneRegistration};
use super::solve::{FrameMetrics, Mapper, SolverOptions};
use super::trajectory::{check_frame, registration_for};
use super::{MAX_FINGERS, MappingError, Registration};
use crate::human::keypoints::{KeypointFrame, human_frame};
use crate::human::{ArmDims, Handedness, HumanError};

/// Settings of one retargeting stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetargetOptions {
    pub handedness: Handedness,
    /// Low-pass cutoff on the output joint values, Hz (`None`: off).
    pub cutoff_hz: Option<f64>,
    /// Output joint speed bound as a multiple of each joint's URDF velocity limit (`None`: off;
    /// the solver's own step box, `step_scale` × the limit, still applies).
    pub speed_scale: Option<f64>,
    /// Fingertips relative to the wrist scaled by this (1: unscaled, as the mapping's default).
    pub hand_scale: f64,
    /// Arm systems: where the first frame's wrist lands, robot base frame (`None`: from the
    /// scaled human reach, as the mapping's default registration).
    pub placement: Option<Point3<f64>>,
    /// Arm systems: the subject's stature, m, for the human reach of the transport scale.
    pub stature_m: f64,
    pub weights: Weights,
    pub solver: SolverOptions,
}

impl Default for RetargetOptions {
    fn default() -> Self {
        Self {
            handedness: Handedness::Right,
            cutoff_hz: None,
            speed_scale: None,
            hand_scale: 1.0,
            placement: None,
            stature_m: crate::human::anthropometry::DEFAULT_STATURE_M,
            weights: Weights::default(),
            solver: SolverOptions::default(),
        }
    }
}

/// Why a frame was refused. A refused frame changes nothing: the stream goes on from the last
/// accepted frame.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RetargetError {
    #[error(transparent)]
    Frame(#[from] HumanError),
    #[error("{0}")]
    Mapping(#[from] MappingError),
    #[error("frame time {t} s does not increase past the previous frame's {previous} s")]
    NonIncreasingTime { t: f64, previous: f64 },
    #[error(
        "this system has an arm: every frame needs `elbow` and `shoulder` (only a hand on a fixed \
         base is retargeted from the hand keypoints alone)"
    )]
    MissingArm,
    #[error("option `{field}` is invalid: {value}")]
    InvalidOption { field: &'static str, value: f64 },
}

impl RetargetError {
    /// The request field the error is about (JSON-path tail), for problem details.
    pub fn field(&self) -> String {
        match self {
            Self::Frame(e) => {
                // The frame is the document: drop the stream name and the sample index.
                let p = e.path();
                let p = p.split_once('.').map_or(p.as_str(), |(_, rest)| rest);
                p.split('[').next().unwrap_or(p).to_string()
            }
            Self::NonIncreasingTime { .. } => "t".into(),
            Self::MissingArm => "elbow".into(),
            Self::InvalidOption { field, .. } => (*field).into(),
            Self::Mapping(_) => String::new(),
        }
    }
}

/// One retargeted frame.
#[derive(Clone, Copy, Debug)]
pub struct RetargetStep {
    /// The solve's metrics (errors of the solution, before the output filter).
    pub metrics: FrameMetrics,
    /// `‖x_i − x_goal_i‖` of the output posture per robot finger, m (equal to the solve's when
    /// no filter or bound is set).
    pub output_error: [f64; MAX_FINGERS],
    /// Whether the low-pass or the speed bound moved the output off the solution.
    pub filtered: bool,
    /// Index of this frame in the stream (accepted frames only).
    pub index: usize,
}

/// The retargeting state of one stream.
pub struct Retargeter {
    mapper: Mapper,
    anchor: RobotAnchor,
    options: RetargetOptions,
    reg: Option<Registration>,
    /// Shoulder to middle fingertip of the subject's outstretched arm, m.
    human_reach: f64,
    arm: bool,
    goals: FrameGoals,
    last_t: Option<f64>,
    out: Vec<f64>,
    /// The output started from a given posture ([`Retargeter::start_from`]).
    start: bool,
    vmax: Vec<f64>,
    frames: usize,
}

impl Retargeter {
    pub fn new(mm: MappingModel, options: RetargetOptions) -> Result<Self, RetargetError> {
        if let Some(fc) = options.cutoff_hz
            && !(fc.is_finite() && fc > 0.0)
        {
            return Err(RetargetError::InvalidOption {
                field: "cutoff_hz",
                value: fc,
            });
        }
        if let Some(s) = options.speed_scale
            && !(s.is_finite() && s > 0.0)
        {
            return Err(RetargetError::InvalidOption {
                field: "speed_scale",
                value: s,
            });
        }
        if !(options.hand_scale.is_finite() && options.hand_scale > 0.0) {
            return Err(RetargetError::InvalidOption {
                field: "hand_scale",
                value: options.hand_scale,
            });
        }
        let dims = ArmDims::from_stature(options.stature_m)?;
        let human_reach = dims.upper_arm + dims.forearm + dims.hand;
        let anchor = mm.anchor();
        let arm = anchor.fixed_wrist.is_none();
        if !arm && options.placement.is_some() {
            return Err(MappingError::InvalidPlacement {
                reason: "a hand on a fixed base has no placement: its fingertips are registered \
                         relative to the subject's wrist"
                    .into(),
            }
            .into());
        }
        let fallback = options.solver.fallback_speed;
        let vmax = mm
            .model
            .velocity_limits()
            .iter()
            .map(|&v| {
                if v.is_finite() && v > 0.0 {
                    v
                } else {
                    fallback
                }
            })
            .collect();
        let nq = mm.model.nq();
        let mapper = Mapper::new(mm, options.weights, options.solver)?;
        Ok(Self {
            mapper,
            anchor,
            options,
            reg: None,
            human_reach,
            arm,
            goals: FrameGoals::default(),
            last_t: None,
            out: vec![0.0; nq],
            start: false,
            vmax,
            frames: 0,
        })
    }

    /// The joint names of [`Self::output`], in order.
    pub fn joint_names(&self) -> &[String] {
        self.mapper.model().model.joint_names()
    }

    /// Whether the system has an arm (frames then need elbow and shoulder).
    pub fn needs_arm(&self) -> bool {
        self.arm
    }

    /// The output joint values of the last accepted frame.
    pub fn output(&self) -> &[f64] {
        &self.out
    }

    /// The registration in use (after the first accepted frame).
    pub fn registration(&self) -> Option<&Registration> {
        self.reg.as_ref()
    }

    /// Starts the output from posture `q` (in [`Self::joint_names`] order; e.g. where a robot
    /// driven by the stream stands): the first frame's output is `q` itself, and from the second
    /// frame on the low-pass and the speed bound move the output from there towards the
    /// solutions, so a teleoperated robot is led from its own posture to the operator's at the
    /// bounded speed rather than sent to a far first setpoint. Before the first frame only;
    /// ignored when `q` has the wrong length or a value that is not finite.
    pub fn start_from(&mut self, q: &[f64]) -> bool {
        let ok = self.frames == 0 && q.len() == self.out.len() && q.iter().all(|x| x.is_finite());
        if ok {
            self.out.copy_from_slice(q);
            self.start = true;
        }
        ok
    }

    /// The goals of the last accepted frame (robot base frame).
    pub fn goals(&self) -> &FrameGoals {
        &self.goals
    }

    /// Retargets one frame. A refused frame leaves the state as it was.
    pub fn push(&mut self, kp: &KeypointFrame) -> Result<RetargetStep, RetargetError> {
        let frame = human_frame(kp, self.options.handedness, "frame", self.frames)?;
        if self.arm && !kp.has_arm() {
            return Err(RetargetError::MissingArm);
        }
        if let Some(previous) = self.last_t
            && kp.t <= previous
        {
            return Err(RetargetError::NonIncreasingTime { t: kp.t, previous });
        }
        check_frame(self.frames, &frame)?;
        let reg = match self.reg {
            Some(r) => r,
            None => {
                let spec = RegistrationSpec::Scene(SceneRegistration {
                    transport_scale: Scale::Factor(self.anchor.reach / self.human_reach),
                    hand_scale: self.options.hand_scale,
                    placement: self.options.placement,
                    ..SceneRegistration::default()
                });
                let reg = registration_for(std::slice::from_ref(&frame), &spec, &self.anchor)?;
                self.mapper.set_scene(&reg);
                if let Some(c) = &mut self.mapper.clearance {
                    // No object in a stream: only the support (and for arm systems the table
                    // under it) is kept clear.
                    c.object = false;
                }
                self.reg = Some(reg);
                reg
            }
        };
        let mut goals = FrameGoals::default();
        self.mapper.goals(&frame, &reg, &mut goals);
        let metrics = match self.last_t {
            None => self.mapper.solve_first(&goals, kp.t),
            Some(previous) => self.mapper.solve_next(&goals, kp.t, kp.t - previous),
        };
        let q = self.mapper.solution();
        let mut filtered = false;
        match self.last_t {
            None if self.start => filtered = self.out != q,
            None => self.out.copy_from_slice(q),
            Some(previous) => {
                let dt = kp.t - previous;
                let alpha = self.options.cutoff_hz.map_or(1.0, |fc| {
                    1.0 - (-2.0 * std::f64::consts::PI * fc * dt).exp()
                });
                for ((out, &qi), &vmax) in self.out.iter_mut().zip(q).zip(&self.vmax) {
                    let mut step = alpha * (qi - *out);
                    if let Some(s) = self.options.speed_scale {
                        let bound = s * vmax * dt;
                        step = step.clamp(-bound, bound);
                    }
                    *out += step;
                    filtered |= *out != qi;
                }
            }
        }
        let mut output_error = metrics.position_error;
        if filtered {
            let eval = &mut self.mapper.eval;
            eval.update(&self.out);
            for (i, e) in output_error.iter_mut().enumerate().take(metrics.fingers) {
                *e = (eval.tip_position(i) - goals.fingers[i].position).norm();
            }
        }
        self.goals = goals;
        self.last_t = Some(kp.t);
        let index = self.frames;
        self.frames += 1;
        Ok(RetargetStep {
            metrics,
            output_error,
            filtered,
            index,
        })
    }
}

pub mod targets;
#[cfg(test)]
mod tests;
