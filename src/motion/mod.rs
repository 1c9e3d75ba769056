//! Low-dimensional humanlike motion: PCA, B-splines, navigation functions, flow, time scaling
//! (paper §III-B, eq. 8-9; DESIGN §5 "PCA + NF").
//!
//! Pipeline: [`train`] takes demonstrated joint trajectories (the mapping's output: per frame the
//! robot's independent joint positions) and per-joint limits, splits the joints into groups (arm,
//! hand), and for each group learns a PCA manifold ([`Pca`]) and, in its coordinates `y`, a
//! navigation function ([`NavigationFunction`]) `φ = γ/(γ^k + β)^{1/k}` whose fictitious obstacle
//! `β = β_0·exp(s(y))` carries a tensor-product cubic B-spline `s` ([`TensorBSpline`]) fitted to the
//! demonstrated velocity directions. Every model carries a convergence [`Certificate`]: the
//! closed-form bound under which `γ` strictly decreases (the default), or navigation-function
//! theory's "no critical point but the goal", proved by branch and bound ([`no_critical_point`],
//! [`CertificateKind`]), under which `γ` may rise; the integrator ([`integrate_flow`]) assumes
//! only the latter, which the former implies. [`MotionModel::trajectory`] integrates the flow, back-projects it with the
//! exact start and goal kept, and times it; [`PathFollower`] is the closed-loop law that runs
//! that timed path with a governed clock, and [`ControlParams::control`] the bare law (eq. 8) for
//! a goal without a path.
//!
//! Feeding the mapping's output: one [`JointTrajectory`] per mapped demonstration, `times` the
//! resampled frame times and `positions` the robot's independent joint values per frame
//! (row-major, in `Model::joint_names()` order); [`JointLimits`] from the model's limits (the
//! acceleration limits come from the system descriptor or a configured default); groups =
//! `[system.arm joint indices, system.hand joint indices]`. The API layer keeps the joint names
//! and checks them; this module works on indices only.
//!
//! Deviation from DESIGN §5, with reasons: `φ` is evaluated in PCA coordinates scaled by the
//! workspace diameter (see [`NavigationFunction`]); the certificate's goal region is a ball
//! around the demonstrated final points (not the whole data), which keeps the bound useful; the
//! spline fit leaves out points near their own goal (`TrainOptions::goal_exclusion`).
//!
//! Second deviation, opt-in in this module (`TrainOptions::profile_ridge`) and on by default in
//! the service: a goal-conditioned residual profile ([`ResidualProfile`], linear in the start and
//! goal of all joints, [`ProfileInputs`]) added to the back-projected NF path, zero at both ends.
//! Why: on mapped
//! demonstrations the flow alone reproduces almost nothing (held-out NF / joint line 0.97-1.00 on
//! all six bundled systems), because what separates them from the straight path is out of a
//! goal-directed, goal-independent field's reach: the flow strictly decreases `γ`, while the
//! mapped paths increase it over 13-39 % of their PCA-space arc (the hand opens before it closes:
//! `γ` peaks at 2.6-17× its start value; arm joints overshoot), the deviation changes sign between
//! object positions, and 35-62 % of the arm's deviation (norm) lies off the manifold, which the
//! back-projection interpolates linearly. The profile keeps the exact start and goal and leaves the
//! flow, its certificate and the closed-loop law as they are; it only shapes the way there. With
//! it the held-out ratio falls to 0.55-0.72 (`examples/motion_heldout.rs`; the one above 0.7,
//! wam_ihy, has demonstrations whose mapped wrist passes its singularity to the other branch).

// Numeric kernels index several parallel fixed-size arrays with one loop variable; iterator
// chains over 3-5 zipped arrays read worse than the formulas they implement.
#![allow(clippy::needless_range_loop)]

mod baselines;
mod bspline;
mod control;
mod critical;
mod error;
mod fit;
mod flow;
mod follow;
mod lp;
pub mod mapped;
mod model;
mod nf;
mod pca;
mod retime;
pub use retime::{arrival_progress, clearance_progress, cubic_basis};
pub mod synthetic;
#[cfg(test)]
mod tests;
mod timing;

pub use baselines::{Dmp, ProMp};
pub use bspline::{MAX_DIM, TensorBSpline};
pub use control::ControlParams;
pub use critical::{BOX_BUDGET, CriticalPointCertificate, no_critical_point};
pub use error::MotionError;
pub use fit::{MAX_COEFFICIENTS as MAX_SPLINE_COEFFICIENTS, SplineFit};
pub use flow::{FlowOptions, FlowPath, integrate_flow};
pub use follow::{CLOCK_TOLERANCE, PathFollower};
pub use model::{
    Baseline, DEFAULT_PROFILE_RIDGE, DurationModel, ENTRY_DEPTH, HeldOutReport, JointLimits,
    JointTrajectory, KChoice, MAX_SPLINE_INTERVALS, ManifoldFit, ManifoldModel, MotionModel,
    PhaseMap, ProfileInputs, ResidualProfile, TrainOptions, TrainReport, Trajectory,
    TrajectoryOptions, TrajectoryPoint, WorkspaceEntry, arc_length_deviation, train,
};
pub use nf::{Certificate, CertificateKind, NavigationFunction};
pub use pca::{Components, Pca};
pub use timing::{MinimumJerk, NaturalCubic, Pchip};
