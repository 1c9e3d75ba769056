//! The robot-client seam, shaped like openrr's `arci::JointTrajectoryClient`: a trajectory is
//! either refused at submission ([`Rejected`]) or accepted, and then the motion ends later
//! ([`Completion`] resolves to [`Finished`]). Those are separate outcomes on purpose: a caller
//! must be able to tell "the robot never moved" from "the robot moved and stopped".
//!
//! - [`HubClient`]: the WebSocket implementation (queues through the [`Hub`], a connected
//!   worker runs it).
//! - [`FakeClient`]: in-process, records what it was sent (for tests of code that drives a robot).
//! - [`LimitChecked`]: a decorator over any client that refuses a trajectory breaking the URDF
//!   limits (position, velocity; acceleration where the caller knows one: URDF has none).

use std::future::Future;
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use futures::future::BoxFuture;

use super::{BridgeError, Hub, WorkerName};
use crate::kinematics::Model;
use crate::motion::TrajectoryPoint;
use crate::store::executions::ExecutionState;
use crate::store::payload::{ExecutionPayload, Mode};

/// A timed joint trajectory for one robot, joints in the client's order.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub joint_names: Vec<String>,
    pub points: Vec<TrajectoryPoint>,
}

/// Why a trajectory was refused before anything moved.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Rejected {
    #[error("joint names {got:?} are not the client's {expected:?}")]
    JointNames {
        expected: Vec<String>,
        got: Vec<String>,
    },
    #[error("point {point}: {what}")]
    Malformed { point: usize, what: String },
    #[error(
        "point {point}: joint '{joint}' at {value} is outside its position limits [{lower}, {upper}]"
    )]
    Position {
        point: usize,
        joint: String,
        value: f64,
        lower: f64,
        upper: f64,
    },
    /// `value` is the declared velocity or the mean velocity between this point and the previous
    /// one, whichever breaks the limit.
    #[error("point {point}: joint '{joint}' moves at {value} beyond its velocity limit {limit}")]
    Velocity {
        point: usize,
        joint: String,
        value: f64,
        limit: f64,
    },
    #[error(
        "point {point}: joint '{joint}' accelerates at {value} beyond its acceleration limit {limit}"
    )]
    Acceleration {
        point: usize,
        joint: String,
        value: f64,
        limit: f64,
    },
    /// Refused by the bridge (unknown robot, payload not fitting the robot, store failure).
    #[error(transparent)]
    Bridge(#[from] BridgeError),
}

/// How an accepted motion ended.
#[derive(Debug, Clone, PartialEq)]
pub struct Finished {
    /// One of the final states (`succeeded`, `failed`, `aborted`, `cancelled`, `interrupted`).
    pub state: ExecutionState,
    pub reason: Option<String>,
}

/// The end of an accepted motion; await it (dropping it does not stop the robot, but then nobody
/// learns how the motion ended, hence `must_use` as in `arci::WaitFuture`).
#[must_use = "a motion's end is only known by awaiting its completion"]
pub struct Completion {
    /// The execution id when the motion runs on a bridge worker.
    pub execution_id: Option<String>,
    wait: BoxFuture<'static, Result<Finished, BridgeError>>,
}

impl Completion {
    /// A completion whose end is already known.
    pub fn ready(finished: Finished) -> Completion {
        Completion {
            execution_id: None,
            wait: Box::pin(std::future::ready(Ok(finished))),
        }
    }
}

impl Future for Completion {
    type Output = Result<Finished, BridgeError>;
    fn poll(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Self::Output> {
        self.wait.as_mut().poll(cx)
    }
}

impl std::fmt::Debug for Completion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Completion")
            .field("execution_id", &self.execution_id)
            .finish_non_exhaustive()
    }
}

/// Something that runs joint trajectories on one robot.
pub trait TrajectoryClient: Send + Sync {
    /// The joints a trajectory must name, in this order.
    fn joint_names(&self) -> &[String];

    /// Submits a trajectory. `Err`: refused, nothing moved. `Ok`: accepted; the completion
    /// resolves when the motion has ended.
    fn send_trajectory(
        &self,
        trajectory: Trajectory,
    ) -> impl Future<Output = Result<Completion, Rejected>> + Send;
}

// ---------------------------------------------------------------------- WebSocket (hub)

/// Runs trajectories on bridge workers connected over the WebSocket, through the hub's
/// persistent queue (the hub validates the payload against the robot again).
#[derive(Debug, Clone)]
pub struct HubClient {
    hub: Hub,
    robot: String,
    joint_names: Vec<String>,
    worker: Option<WorkerName>,
}

impl HubClient {
    /// A client for `robot` (its joints come from the robot library); `worker` pins the
    /// executions to one named worker.
    pub async fn new(
        hub: Hub,
        robot: &str,
        worker: Option<WorkerName>,
    ) -> Result<HubClient, BridgeError> {
        let system = hub.robots().system(robot).await?;
        Ok(HubClient {
            joint_names: system.model.joint_names().to_vec(),
            hub,
            robot: robot.to_owned(),
            worker,
        })
    }
}

impl TrajectoryClient for HubClient {
    fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    async fn send_trajectory(&self, trajectory: Trajectory) -> Result<Completion, Rejected> {
        let trajectory = same_joints(&self.joint_names, trajectory)?;
        let payload = ExecutionPayload::Trajectory {
            trajectory_id: "inline".into(),
            joint_names: trajectory.joint_names,
            points: trajectory.points,
        };
        let id = self
            .hub
            .enqueue(&self.robot, Mode::OpenLoop, payload, self.worker.clone())
            .await?;
        let hub = self.hub.clone();
        let wait_id = id.clone();
        Ok(Completion {
            execution_id: Some(id),
            wait: Box::pin(async move { hub.wait_final(&wait_id).await }),
        })
    }
}

/// Every client takes a trajectory only in its own joint order.
fn same_joints(expected: &[String], trajectory: Trajectory) -> Result<Trajectory, Rejected> {
    if trajectory.joint_names == expected {
        Ok(trajectory)
    } else {
        Err(Rejected::JointNames {
            expected: expected.to_vec(),
            got: trajectory.joint_names,
        })
    }
}

// ---------------------------------------------------------------------- fake

/// An in-process client that records every trajectory it accepts and ends each motion with a
/// chosen state (`succeeded` unless told otherwise).
#[derive(Debug, Clone)]
pub struct FakeClient {
    joint_names: Vec<String>,
    sent: Arc<Mutex<Vec<Trajectory>>>,
    ends: ExecutionState,
}

impl FakeClient {
    pub fn new(joint_names: Vec<String>) -> FakeClient {
        FakeClient {
            joint_names,
            sent: Arc::default(),
            ends: ExecutionState::Succeeded,
        }
    }

    /// Every accepted motion ends in `state` (a final state).
    pub fn ending_with(mut self, state: ExecutionState) -> FakeClient {
        self.ends = state;
        self
    }

    /// The trajectories accepted so far, in order.
    pub fn sent(&self) -> Vec<Trajectory> {
        self.sent.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

impl TrajectoryClient for FakeClient {
    fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    async fn send_trajectory(&self, trajectory: Trajectory) -> Result<Completion, Rejected> {
        let trajectory = same_joints(&self.joint_names, trajectory)?;
        self.sent
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(trajectory);
        Ok(Completion::ready(Finished {
            state: self.ends,
            reason: None,
        }))
    }
}

// ---------------------------------------------------------------------- limits

/// Per-joint limits a [`LimitChecked`] client enforces; `f64::INFINITY` means unbounded.
#[derive(Debug, Clone, PartialEq)]
pub struct JointLimits {
    pub joint_names: Vec<String>,
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
    pub velocity: Vec<f64>,
    pub acceleration: Vec<f64>,
}

impl JointLimits {
    /// Position and velocity limits from the URDF (through the model); accelerations unbounded
    /// because URDF has no acceleration limit (set them with [`JointLimits::with_acceleration`]).
    pub fn from_model(model: &Model) -> JointLimits {
        let n = model.nq();
        JointLimits {
            joint_names: model.joint_names().to_vec(),
            lower: model.lower_limits().to_vec(),
            upper: model.upper_limits().to_vec(),
            velocity: model.velocity_limits().to_vec(),
            acceleration: vec![f64::INFINITY; n],
        }
    }

    /// Acceleration limits known from elsewhere (a datasheet), one per joint.
    pub fn with_acceleration(mut self, acceleration: Vec<f64>) -> JointLimits {
        assert_eq!(acceleration.len(), self.joint_names.len());
        self.acceleration = acceleration;
        self
    }

    /// The first violation in `trajectory`, if any. Besides the declared velocities, the mean
    /// velocity between consecutive points must respect the limit: a trajectory that declares
    /// zero velocity while its positions jump would otherwise pass.
    pub fn check(&self, trajectory: &Trajectory) -> Result<(), Rejected> {
        // Slack for rounding in the producer (times and positions printed with finite digits).
        const TOL: f64 = 1e-9;
        if trajectory.joint_names != self.joint_names {
            return Err(Rejected::JointNames {
                expected: self.joint_names.clone(),
                got: trajectory.joint_names.clone(),
            });
        }
        let n = self.joint_names.len();
        let name = |j: usize| self.joint_names[j].clone();
        for (i, p) in trajectory.points.iter().enumerate() {
            let malformed = |what: String| Rejected::Malformed { point: i, what };
            for (field, v) in [
                ("positions", &p.positions),
                ("velocities", &p.velocities),
                ("accelerations", &p.accelerations),
            ] {
                if v.len() != n {
                    return Err(malformed(format!("{} {field} for {n} joints", v.len())));
                }
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(malformed(format!("{field} must be finite")));
                }
            }
            if !p.t.is_finite() {
                return Err(malformed("t must be finite".into()));
            }
            let prev = i.checked_sub(1).map(|k| &trajectory.points[k]);
            if let Some(prev) = prev
                && p.t <= prev.t
            {
                return Err(malformed(format!("t {} does not follow {}", p.t, prev.t)));
            }
            for j in 0..n {
                let (q, lo, hi) = (p.positions[j], self.lower[j], self.upper[j]);
                if q < lo - TOL || q > hi + TOL {
                    return Err(Rejected::Position {
                        point: i,
                        joint: name(j),
                        value: q,
                        lower: lo,
                        upper: hi,
                    });
                }
                let mean = prev.map_or(0.0, |prev| {
                    (p.positions[j] - prev.positions[j]) / (p.t - prev.t)
                });
                let v = if p.velocities[j].abs() >= mean.abs() {
                    p.velocities[j]
                } else {
                    mean
                };
                if v.abs() > self.velocity[j] * (1.0 + TOL) {
                    return Err(Rejected::Velocity {
                        point: i,
                        joint: name(j),
                        value: v,
                        limit: self.velocity[j],
                    });
                }
                let a = p.accelerations[j];
                if a.abs() > self.acceleration[j] * (1.0 + TOL) {
                    return Err(Rejected::Acceleration {
                        point: i,
                        joint: name(j),
                        value: a,
                        limit: self.acceleration[j],
                    });
                }
            }
        }
        Ok(())
    }
}

/// A client that refuses trajectories outside [`JointLimits`] before its inner client sees them
/// (like `arci`'s limiter decorators, but refusing instead of clamping: a clamped trajectory is
/// no longer the one that was planned and checked for collisions).
#[derive(Debug, Clone)]
pub struct LimitChecked<C> {
    inner: C,
    limits: JointLimits,
}

impl<C: TrajectoryClient> LimitChecked<C> {
    /// Wraps `inner`; the limits must name the same joints in the same order.
    pub fn new(inner: C, limits: JointLimits) -> Result<LimitChecked<C>, Rejected> {
        if inner.joint_names() != limits.joint_names.as_slice() {
            return Err(Rejected::JointNames {
                expected: inner.joint_names().to_vec(),
                got: limits.joint_names,
            });
        }
        Ok(LimitChecked { inner, limits })
    }

    /// Wraps `inner` with the model's URDF limits.
    pub fn from_model(inner: C, model: &Model) -> Result<LimitChecked<C>, Rejected> {
        Self::new(inner, JointLimits::from_model(model))
    }

    pub fn inner(&self) -> &C {
        &self.inner
    }

    pub fn limits(&self) -> &JointLimits {
        &self.limits
    }
}

impl<C: TrajectoryClient> TrajectoryClient for LimitChecked<C> {
    fn joint_names(&self) -> &[String] {
        self.inner.joint_names()
    }

    async fn send_trajectory(&self, trajectory: Trajectory) -> Result<Completion, Rejected> {
        self.limits.check(&trajectory)?;
        self.inner.send_trajectory(trajectory).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::{NoMeshes, model_from_urdf_str};

    /// Two revolute joints; shoulder: [-1, 1] rad, 0.5 rad/s; elbow: [-2, 0.5] rad, 2 rad/s.
    const ARM: &str = r#"<robot name="arm"><link name="base"/><link name="upper"/><link name="fore"/>
      <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="0.5"/></joint>
      <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>
        <origin xyz="0.3 0 0"/><axis xyz="0 0 1"/>
        <limit lower="-2" upper="0.5" effort="10" velocity="2"/></joint></robot>"#;

    fn names() -> Vec<String> {
        vec!["shoulder".into(), "elbow".into()]
    }

    fn point(t: f64, q: [f64; 2], v: [f64; 2], a: [f64; 2]) -> TrajectoryPoint {
        TrajectoryPoint {
            t,
            positions: q.to_vec(),
            velocities: v.to_vec(),
            accelerations: a.to_vec(),
        }
    }

    /// 0.4 rad of shoulder in 2 s (mean 0.2 rad/s), elbow still: inside every URDF limit.
    fn within() -> Trajectory {
        Trajectory {
            joint_names: names(),
            points: vec![
                point(0.0, [0.0, 0.0], [0.0, 0.0], [0.3, 0.0]),
                point(1.0, [0.2, 0.0], [0.3, 0.0], [0.0, 0.0]),
                point(2.0, [0.4, 0.0], [0.0, 0.0], [-0.3, 0.0]),
            ],
        }
    }

    fn checked(fake: &FakeClient) -> LimitChecked<FakeClient> {
        let model = model_from_urdf_str(ARM, &NoMeshes).unwrap();
        LimitChecked::from_model(fake.clone(), &model).unwrap()
    }

    #[tokio::test]
    async fn the_fake_records_what_it_was_sent_and_ends_as_told() {
        let fake = FakeClient::new(names()).ending_with(ExecutionState::Aborted);
        let first = within();
        let mut second = within();
        second.points.truncate(2);
        let done = fake.send_trajectory(first.clone()).await.unwrap().await;
        assert_eq!(done.unwrap().state, ExecutionState::Aborted);
        let _ = fake.send_trajectory(second.clone()).await.unwrap().await;
        assert_eq!(fake.sent(), vec![first, second]);

        let mut swapped = within();
        swapped.joint_names.reverse();
        let refused = fake.send_trajectory(swapped).await.unwrap_err();
        assert!(matches!(refused, Rejected::JointNames { .. }), "{refused}");
        assert_eq!(fake.sent().len(), 2, "a refused trajectory is not recorded");
    }

    #[test]
    fn limits_come_from_the_urdf() {
        let model = model_from_urdf_str(ARM, &NoMeshes).unwrap();
        let l = JointLimits::from_model(&model);
        assert_eq!(l.joint_names, names());
        assert_eq!(l.lower, vec![-1.0, -2.0]);
        assert_eq!(l.upper, vec![1.0, 0.5]);
        assert_eq!(l.velocity, vec![0.5, 2.0]);
        assert!(l.acceleration.iter().all(|a| a.is_infinite()));
    }

    #[tokio::test]
    async fn a_trajectory_within_the_limits_reaches_the_robot() {
        let fake = FakeClient::new(names());
        let done = checked(&fake)
            .send_trajectory(within())
            .await
            .unwrap()
            .await;
        assert_eq!(done.unwrap().state, ExecutionState::Succeeded);
        assert_eq!(fake.sent(), vec![within()]);
    }

    #[tokio::test]
    async fn a_position_over_the_limit_is_refused_before_the_robot() {
        let fake = FakeClient::new(names());
        let mut t = within();
        // Elbow upper limit is 0.5 rad.
        t.points[1].positions[1] = 0.51;
        t.points[2].positions[1] = 0.0;
        match checked(&fake).send_trajectory(t).await.unwrap_err() {
            Rejected::Position {
                point,
                joint,
                value,
                upper,
                ..
            } => {
                assert_eq!(
                    (point, joint.as_str(), value, upper),
                    (1, "elbow", 0.51, 0.5)
                );
            }
            other => panic!("expected a position refusal, got {other}"),
        }
        assert!(fake.sent().is_empty());
    }

    #[tokio::test]
    async fn a_declared_velocity_over_the_limit_is_refused() {
        let fake = FakeClient::new(names());
        let mut t = within();
        t.points[1].velocities[0] = -0.6; // shoulder limit 0.5 rad/s
        match checked(&fake).send_trajectory(t).await.unwrap_err() {
            Rejected::Velocity {
                point,
                joint,
                value,
                limit,
            } => assert_eq!(
                (point, joint.as_str(), value, limit),
                (1, "shoulder", -0.6, 0.5)
            ),
            other => panic!("expected a velocity refusal, got {other}"),
        }
        assert!(fake.sent().is_empty());
    }

    #[tokio::test]
    async fn positions_that_jump_faster_than_the_limit_are_refused_whatever_velocity_is_declared() {
        let fake = FakeClient::new(names());
        let mut t = within();
        // 0.2 -> 0.9 rad in 1 s is 0.7 rad/s on average, over 0.5 rad/s, though each point
        // declares 0.3 rad/s or less.
        t.points[2].positions[0] = 0.9;
        match checked(&fake).send_trajectory(t).await.unwrap_err() {
            Rejected::Velocity { point, value, .. } => {
                assert_eq!(point, 2);
                assert!((value - 0.7).abs() < 1e-12, "{value}");
            }
            other => panic!("expected a velocity refusal, got {other}"),
        }
        assert!(fake.sent().is_empty());
    }

    #[tokio::test]
    async fn accelerations_are_checked_where_a_limit_is_known() {
        let model = model_from_urdf_str(ARM, &NoMeshes).unwrap();
        let fake = FakeClient::new(names());
        // URDF has no acceleration limit: 0.3 rad/s² passes.
        let open = LimitChecked::from_model(fake.clone(), &model).unwrap();
        let _ = open.send_trajectory(within()).await.unwrap().await;
        let limits = JointLimits::from_model(&model).with_acceleration(vec![0.25, 1.0]);
        let strict = LimitChecked::new(fake.clone(), limits).unwrap();
        match strict.send_trajectory(within()).await.unwrap_err() {
            Rejected::Acceleration {
                point,
                joint,
                value,
                limit,
            } => assert_eq!(
                (point, joint.as_str(), value, limit),
                (0, "shoulder", 0.3, 0.25)
            ),
            other => panic!("expected an acceleration refusal, got {other}"),
        }
        assert_eq!(
            fake.sent().len(),
            1,
            "only the unchecked-acceleration send went through"
        );
    }

    #[test]
    fn limits_for_other_joints_cannot_wrap_a_client() {
        let model = model_from_urdf_str(ARM, &NoMeshes).unwrap();
        let fake = FakeClient::new(vec!["elbow".into(), "shoulder".into()]);
        assert!(LimitChecked::from_model(fake, &model).is_err());
    }
}
