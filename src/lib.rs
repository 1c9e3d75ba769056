//! reachgrasp: humanlike, task-specific reaching and grasping for redundant arms and
//! low-complexity hands, as an HTTP planning service.
//!
//! Pure computation (no I/O, no async, deterministic for a seed): [`kinematics`], [`geometry`], [`human`],
//! [`mapping`], [`motion`], [`grasp`], [`optim`], [`figures`], and their one parallel map,
//! [`parallel`], and [`wire`], the request-body deserialisation that keeps field paths. The service shell around them, in
//! layers (see [`service`] for the order and the test that keeps it): [`store`] and
//! [`shutdown`]; [`jobs`] and [`bridge`]; the use cases in [`service`] with the typed
//! [`config`]; the edges [`api`], [`dashboard`] and the CLI, wired together by [`app`]. Equation numbers refer to
//! `shared/reference/humanlike-grasping-paper.md`.

pub mod api;
pub mod app;
pub mod bridge;
pub mod config;
pub mod dashboard;
pub mod figures;
pub mod geometry;
pub mod grasp;
pub mod human;
pub mod jobs;
pub mod kinematics;
pub mod mapping;
pub mod motion;
pub mod optim;
pub mod parallel;
pub mod seed;
pub mod service;
pub mod shutdown;
pub mod store;
pub mod wire;
