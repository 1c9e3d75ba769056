//! Low-dimensional humanlike motion: PCA, B-splines, navigation functions, flow, time scaling
//! (paper §III-B, eq. 8-9; DESIGN §5 "PCA + NF").
//!
//! Pipeline: [`train`] takes demonstrated joint trajectories (the mapping's output: per frame the
//! robot's independent joint positions) and per-joint limits, splits the joints into groups (arm,
//! hand), and for each group learns a PCA manifold ([`Pca`]) with its curvature
//! ([`curvature::Curvature`]: the off-manifold residual as a quadratic function of `y`) and, in
//! its coordinates `y`, a navigation function ([`NavigationFunction`]) `φ = γ/(γ^k + β)^{1/k}`
//! whose fictitious obstacle `β = β_0·exp(s(y))` carries a tensor-product cubic B-spline `s`
//! ([`TensorBSpline`]) fitted to the demonstrated velocity directions. Every model carries a
//! [`Certificate`]: the navigation-function property (theorem and proof sketch in
//! [`critical`]): `φ` has no critical point in the workspace ball but the goal, for every goal in
//! the goal region, and the boundary repels, so the flow converges from every start to every
//! goal while `γ` may rise on the way. [`MotionModel::trajectory`] integrates the flow,
//! back-projects it onto the curved manifold with the exact start and goal kept, and times it;
//! [`ControlParams::control`] is the closed-loop law, which runs the same path.
//!
//! Feeding the mapping's output: one [`JointTrajectory`] per mapped demonstration, `times` the
//! resampled frame times and `positions` the robot's independent joint values per frame
//! (row-major, in `Model::joint_names()` order); [`JointLimits`] from the model's limits (the
//! acceleration limits come from the system descriptor or a configured default); groups =
//! `[system.arm joint indices, system.hand joint indices]`. The API layer keeps the joint names
//! and checks them; this module works on indices only.
//!
//! Deviations from the paper and DESIGN §5, with reasons:
//! - `φ` is evaluated in PCA coordinates scaled by the workspace diameter (see
//!   [`NavigationFunction`]); the certificate's goal region is a ball around the demonstrated
//!   final points (not the whole data); the spline fit leaves out points near their own goal
//!   (`TrainOptions::goal_exclusion`).
//! - `k` is tuned as Rimon and Koditschek do (the smallest candidate whose unshrunk field is
//!   certified); when no candidate certifies the unshrunk fit, the field is shrunk by bisection
//!   to the largest certified factor (`Certificate::shrink`). The bare workspace ball is a
//!   navigation function for every `k ≥ 1`, so any `k ≥ 1` is accepted.
//! - The back-projection is onto a *curved* manifold `μ + W y + R(y)` (the paper's is linear),
//!   because 35-62 % of the mapped arm's deviation from the joint line lies off the linear one.
//! - The closed-loop law ([`ControlLaw::PhiDecay`]) is eq. 8's direction (`−∇φ`) at the speed
//!   that makes `φ` decay exponentially, plus the off-manifold offset decaying at the same rate;
//!   eq. 8's `−K_p∇φ` has the same orbits on the manifold, but its speed, and so the off-manifold
//!   path, differ from the open-loop plan. The two groups (arm, hand) are coupled by equal `φ`
//!   ratios in both loops (the learned arc-length phase maps remain for the baselines and the
//!   residual profile).
//! - Opt-in (`TrainOptions::profile_ridge`, on by default in the service): a goal-conditioned
//!   residual profile ([`ResidualProfile`], linear in the start and goal of all joints,
//!   [`ProfileInputs`]) added to the back-projected NF path, zero at both ends. It is an
//!   open-loop option: the closed-loop law does not run it. The held-out table
//!   (`cargo run --release --example motion_heldout`) reports the NF path with and without it,
//!   next to the joint line, the PCA line, a DMP and a ProMP.

// Numeric kernels index several parallel fixed-size arrays with one loop variable; iterator
// chains over 3-5 zipped arrays read worse than the formulas they implement.
#![allow(clippy::needless_range_loop)]

pub mod baselines;
mod bspline;
mod control;
pub mod critical;
pub mod curvature;
mod error;
mod fit;
mod flow;
pub mod mapped;
mod model;
mod nf;
mod pca;
pub mod synthetic;
#[cfg(test)]
mod tests;
mod timing;

pub use bspline::{MAX_DIM, TensorBSpline};
pub use control::{ControlGroup, ControlLaw, ControlParams};
pub use error::MotionError;
pub use fit::{MAX_COEFFICIENTS as MAX_SPLINE_COEFFICIENTS, SplineFit};
pub use flow::{FlowOptions, FlowPath, integrate_flow};
pub use model::{
    Baseline, DEFAULT_CURVATURE_RIDGE, DEFAULT_PROFILE_RIDGE, DurationModel, HeldOutReport,
    JointLimits, JointTrajectory, KChoice, ManifoldFit, ManifoldModel, MotionModel, PhaseMap,
    ProfileInputs, ResidualProfile, TrainOptions, TrainReport, Trajectory, TrajectoryOptions,
    TrajectoryPoint, arc_length_deviation, train,
};
pub use nf::{Certificate, NavigationFunction};
pub use pca::{Components, Pca};
pub use timing::{MinimumJerk, NaturalCubic, Pchip};
