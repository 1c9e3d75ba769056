//! Mapping whole demonstrations: registration, goals per frame, the frame solver in sequence,
//! and batches across threads.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use super::MappingError;
use super::goals::finger_goals;
use super::objective::{FrameGoals, MappingModel, Weights, swivel_direction};
use super::registration::{ArmPoints, Registration, RegistrationSpec, RobotAnchor};
use super::solve::{Clearance, FrameMetrics, Mapper, SolverOptions, StartReference};
use crate::geometry::{
    AllowedContacts, Category, CollisionChecker, Member, Plane, Scene, SceneShape, ShapeSpec,
    build_shape,
};
use crate::human::{HumanFrame, ObjectShape};
use nalgebra::Point3;

/// A demonstration mapped onto the robot.
#[derive(Clone, Debug, PartialEq)]
pub struct MappedTrajectory {
    /// Independent joints, the order of each row of `positions`.
    pub joint_names: Vec<String>,
    pub times: Vec<f64>,
    /// Row-major `frames × nq` joint positions.
    pub positions: Vec<f64>,
    pub metrics: Vec<FrameMetrics>,
    pub registration: Registration,
}

impl MappedTrajectory {
    pub fn nq(&self) -> usize {
        self.joint_names.len()
    }
    pub fn frame(&self, k: usize) -> &[f64] {
        let nq = self.nq();
        &self.positions[k * nq..(k + 1) * nq]
    }
    /// Indices of the frames that did not converge.
    pub fn unconverged(&self) -> impl Iterator<Item = usize> + '_ {
        self.metrics
            .iter()
            .enumerate()
            .filter(|(_, m)| !m.converged)
            .map(|(k, _)| k)
    }
}

impl Mapper {
    /// Goals of one human frame in the robot base frame.
    pub fn goals(&self, frame: &HumanFrame, reg: &Registration, out: &mut FrameGoals) {
        let wrist = Point3::from(frame.wrist.translation.vector);
        let tips: [_; 5] = std::array::from_fn(|i| {
            let iso = &frame.fingertips[i];
            reg.hand_tip(iso, &frame.wrist).unwrap_or_else(|| {
                (
                    reg.hand_point(&iso.translation.vector.into(), &wrist),
                    reg.orientation(&iso.rotation),
                )
            })
        });
        let mm = self.eval.model();
        finger_goals(&tips, mm.fingers(), mm.thumb, &mut out.fingers);
        out.elbow = reg.point(&frame.elbow);
        out.shoulder = reg.point(&frame.shoulder);
        out.wrist = reg.point(&wrist);
        out.swivel = swivel_direction(&out.shoulder, &out.elbow, &out.wrist);
    }

    /// The clearance penalty and metrics of the next frames act in this registration's scene
    /// (with [`MappingModel::geometry`]).
    pub fn set_scene(&mut self, reg: &Registration) {
        let model = &self.eval.model().model;
        self.clearance = self.geometry.as_ref().map(|g| {
            let checker = CollisionChecker::new(g.clone(), scene_of(reg))
                .with_allowed(&standing_contacts(g, &reg.up));
            Clearance::new(checker, model)
        });
    }

    /// Maps a whole demonstration on its own: its first frame is solved by the multi-start.
    pub fn map(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
    ) -> Result<MappedTrajectory, MappingError> {
        self.map_cancellable(frames, spec, robot, None, &AtomicBool::new(false))
            .expect("never cancelled")
    }

    /// Maps a demonstration of a batch: its first frame is solved from the batch's reference
    /// posture ([`Self::solve_first_from`]). This is what [`map_batch`] does per demonstration.
    pub fn map_from(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
        reference: &StartReference,
    ) -> Result<MappedTrajectory, MappingError> {
        self.map_cancellable(
            frames,
            spec,
            robot,
            Some(reference),
            &AtomicBool::new(false),
        )
        .expect("never cancelled")
    }

    /// The reference first-frame posture of a batch led by this demonstration: the multi-start
    /// solution of its first frame (the same frame [`Self::map`] would start with).
    pub fn start_reference(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
    ) -> Result<StartReference, MappingError> {
        let reg = registration_for(frames, spec, robot)?;
        let first = frames.first().ok_or(MappingError::EmptyDemonstration)?;
        check_frame(0, first)?;
        let mut goals = FrameGoals::default();
        self.goals(first, &reg, &mut goals);
        self.set_scene(&reg);
        self.solve_first(&goals, first.t);
        let (q, objective) = self.chain();
        Ok(StartReference {
            q: q.to_vec(),
            objective,
        })
    }

    /// [`Self::map`] (`reference: None`) or [`Self::map_from`], polling `cancel` between frames
    /// (`None` once cancelled).
    pub fn map_cancellable(
        &mut self,
        frames: &[HumanFrame],
        spec: &RegistrationSpec,
        robot: &RobotAnchor,
        reference: Option<&StartReference>,
        cancel: &AtomicBool,
    ) -> Option<Result<MappedTrajectory, MappingError>> {
        let reg = match registration_for(frames, spec, robot) {
            Ok(r) => r,
            Err(e) => return Some(Err(e)),
        };
        let nq = self.eval.nq();
        let mut out = MappedTrajectory {
            joint_names: self.eval.model().model.joint_names().to_vec(),
            times: Vec::with_capacity(frames.len()),
            positions: Vec::with_capacity(frames.len() * nq),
            metrics: Vec::with_capacity(frames.len()),
            registration: reg,
        };
        let mut goals = FrameGoals::default();
        self.set_scene(&reg);
        let (t0, t1) = (
            frames.first().map_or(0.0, |f| f.t),
            frames.last().map_or(0.0, |f| f.t),
        );
        let object_until = t0 + self.options.object_free_until * (t1 - t0);
        for (k, frame) in frames.iter().enumerate() {
            if cancel.load(Ordering::Relaxed) {
                return None;
            }
            if let Err(e) = check_frame(k, frame) {
                return Some(Err(e));
            }
            // `t` is finite here (checked above), so `<=` is the full negation of `>`.
            if k > 0 && frame.t <= frames[k - 1].t {
                return Some(Err(MappingError::NonIncreasingTime {
                    frame: k,
                    t: frame.t,
                    previous: frames[k - 1].t,
                }));
            }
            self.goals(frame, &reg, &mut goals);
            if let Some(c) = &mut self.clearance {
                c.object = frame.t < object_until;
            }
            let metrics = if k > 0 {
                self.solve_next(&goals, frame.t, frame.t - frames[k - 1].t)
            } else if let Some(r) = reference {
                self.solve_first_from(&goals, frame.t, r)
            } else {
                self.solve_first(&goals, frame.t)
            };
            let mut metrics = metrics;
            if let Some(c) = &mut self.clearance {
                let cl = c.checker.category_clearance(
                    &mut c.data,
                    &self.q,
                    &[Category::Support, Category::Object],
                );
                let finite = |x: f64| if x.is_finite() { x } else { f64::NAN };
                metrics.support_clearance = finite(cl.category_distance(Category::Support));
                metrics.object_clearance = finite(cl.category_distance(Category::Object));
            }
            out.times.push(frame.t);
            out.positions.extend_from_slice(&self.q);
            out.metrics.push(metrics);
        }
        Some(Ok(out))
    }
}

/// Shapes the first joint alone moves about an axis along `up` (the arm's base yaw link): they
/// stand on the support the robot stands on and keep their height in every posture, so their
/// contact with the support is the robot's footing, not a collision.
pub fn standing_contacts(
    geometry: &crate::geometry::RobotGeometry,
    up: &nalgebra::Vector3<f64>,
) -> AllowedContacts {
    let model = geometry.model();
    let mut data = crate::kinematics::Data::new(model);
    crate::kinematics::forward_kinematics(model, &mut data, &vec![0.0; model.nq()]);
    let mut acm = AllowedContacts::none();
    for (i, shape) in geometry.shapes().iter().enumerate() {
        let [joint] = shape.chain.as_slice() else {
            continue;
        };
        let frame = crate::kinematics::FrameId(joint.frame);
        let Some(axis) = model.joint_of_frame(frame).and_then(|j| j.kind.axis()) else {
            continue;
        };
        let world = data.frame(frame).rotation * axis.into_inner();
        if world.cross(up).norm() < 1e-9 {
            acm.allow(Member::Shape(i), Member::Support);
        }
    }
    acm
}

/// The robot-frame scene of a registration: the registered object and the robot's support plane
/// (the half-space below it solid), for the exact clearance metrics.
pub fn scene_of(reg: &Registration) -> Scene {
    let mut scene = Scene::new();
    if let Some(h) = reg.support {
        // `up` is a unit vector (the robot's base axes), so this cannot fail.
        if let Ok(p) = Plane::new(reg.up, h) {
            scene = scene.with_support(p);
        }
    }
    if let Some(o) = &reg.object {
        let mut spec = shape_spec(&o.shape);
        if let Ok(built) = build_shape(&mut spec, "object.shape") {
            scene = scene.with_object(SceneShape::new(
                "object",
                built.shape,
                o.pose * built.local_fix,
            ));
        }
    }
    scene
}

/// A demonstration's object shape as a geometry shape (same axes: cylinders and capsules along
/// local `z`; the human capsule's `height` is its cylindrical part).
pub fn shape_spec(shape: &ObjectShape) -> ShapeSpec {
    match *shape {
        ObjectShape::Sphere { radius } => ShapeSpec::Sphere { radius },
        ObjectShape::Cylinder { radius, height } => ShapeSpec::Cylinder { radius, height },
        ObjectShape::Box { size } => ShapeSpec::Box { size },
        ObjectShape::Capsule { radius, height } => ShapeSpec::Capsule {
            radius,
            length: height,
        },
    }
}

pub(super) fn check_frame(k: usize, f: &HumanFrame) -> Result<(), MappingError> {
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    let fields: [(&'static str, bool); 5] = [
        ("t", f.t.is_finite()),
        ("shoulder", finite(f.shoulder.coords.as_slice())),
        ("elbow", finite(f.elbow.coords.as_slice())),
        (
            "wrist",
            finite(f.wrist.translation.vector.as_slice())
                && finite(f.wrist.rotation.coords.as_slice()),
        ),
        (
            "fingertips",
            f.fingertips.iter().all(|t| {
                finite(t.translation.vector.as_slice()) && finite(t.rotation.coords.as_slice())
            }),
        ),
    ];
    for (field, ok) in fields {
        if !ok {
            return Err(MappingError::NonFinite { frame: k, field });
        }
    }
    Ok(())
}

/// The registration of a demonstration (its arm points, the spec, the robot).
pub fn registration_for(
    frames: &[HumanFrame],
    spec: &RegistrationSpec,
    robot: &RobotAnchor,
) -> Result<Registration, MappingError> {
    let points: Vec<ArmPoints> = frames
        .iter()
        .map(|f| ArmPoints {
            shoulder: f.shoulder,
            elbow: f.elbow,
            wrist: f.wrist.translation.vector.into(),
            middle_tip: f.fingertips[2].translation.vector.into(),
        })
        .collect();
    Registration::resolve(spec, &points, robot)
}

/// Human frames at `rate_hz` on the demonstration's own clock (first frame kept, last time not
/// exceeded): positions interpolated linearly and orientations by slerp, with the same
/// interpolants the ingest uses ([`crate::human::resample`]), so mapping at the demonstration's
/// own rate reproduces its frames. The output rate of a mapping is the rate of its trajectory.
pub fn resample_frames(frames: &[HumanFrame], rate_hz: f64) -> Vec<HumanFrame> {
    use crate::human::resample::{Cursor, lerp, slerp};
    use nalgebra::{Isometry3, Translation3};
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        return Vec::new();
    };
    if frames.len() < 2 || !(rate_hz.is_finite() && rate_hz > 0.0) {
        return frames.to_vec();
    }
    let ts: Vec<f64> = frames.iter().map(|f| f.t).collect();
    let span = last.t - first.t;
    // The small slack keeps the last sample when the span is a whole number of periods.
    let n = (span * rate_hz + 1e-9).floor() as usize + 1;
    let pose = |a: &Isometry3<f64>, b: &Isometry3<f64>, s: f64| {
        Isometry3::from_parts(
            Translation3::from(lerp(&a.translation.vector, &b.translation.vector, s)),
            slerp(&a.rotation, &b.rotation, s),
        )
    };
    let point =
        |a: &Point3<f64>, b: &Point3<f64>, s: f64| Point3::from(lerp(&a.coords, &b.coords, s));
    let mut cursor = Cursor::default();
    (0..n)
        .map(|k| {
            let t = first.t + k as f64 / rate_hz;
            let (i, s) = cursor.locate(&ts, t);
            let (a, b) = (&frames[i], &frames[(i + 1).min(frames.len() - 1)]);
            HumanFrame {
                t,
                shoulder: point(&a.shoulder, &b.shoulder, s),
                elbow: point(&a.elbow, &b.elbow, s),
                wrist: pose(&a.wrist, &b.wrist, s),
                fingertips: std::array::from_fn(|j| pose(&a.fingertips[j], &b.fingertips[j], s)),
            }
        })
        .collect()
}

/// The first-frame postures of a batch, one per demonstration (`None` where its registration
/// or first frame is invalid; it then fails on its own), or `None` once `cancel` is set.
///
/// One consistent posture branch across subjects and trials: the first valid demonstration's
/// first frame is solved by the multi-start ([`Mapper::start_reference`]); every later one, in
/// input order, locally from the first-frame posture of the nearest already-solved
/// demonstration ([`Mapper::solve_first_from`]). "Nearest" compares the registered first-frame
/// goals (fingertip goal positions and the human elbow, summed squared distances); a tie goes
/// to the earlier demonstration. Sequential and on the calling thread, so the result depends
/// only on the batch, never on scheduling.
pub fn batch_starts(
    mapper: &mut Mapper,
    robot: &RobotAnchor,
    items: &[BatchItem<'_>],
    cancel: &AtomicBool,
) -> Option<Vec<Option<StartReference>>> {
    let m = mapper.eval.model().fingers();
    let mut solved: Vec<(FrameGoals, StartReference)> = Vec::new();
    let mut out = Vec::with_capacity(items.len());
    for item in items {
        if cancel.load(Ordering::Relaxed) {
            return None;
        }
        let Some(first) = item.frames.first() else {
            out.push(None);
            continue;
        };
        let Ok(reg) = registration_for(item.frames, item.registration, robot) else {
            out.push(None);
            continue;
        };
        if check_frame(0, first).is_err() {
            out.push(None);
            continue;
        }
        let mut goals = FrameGoals::default();
        mapper.goals(first, &reg, &mut goals);
        mapper.set_scene(&reg);
        let distance = |g: &FrameGoals| {
            (0..m)
                .map(|i| (g.fingers[i].position - goals.fingers[i].position).norm_squared())
                .sum::<f64>()
                + (g.elbow - goals.elbow).norm_squared()
        };
        // `min_by` keeps the first of equal elements: ties go to the earlier demonstration.
        let nearest = solved
            .iter()
            .map(|(g, r)| (distance(g), r))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, r)| r.clone());
        match &nearest {
            Some(r) => mapper.solve_first_from(&goals, first.t, r),
            None => mapper.solve_first(&goals, first.t),
        };
        let (q, objective) = mapper.chain();
        let start = StartReference {
            q: q.to_vec(),
            objective,
        };
        solved.push((goals, start.clone()));
        out.push(Some(start));
    }
    Some(out)
}

/// One demonstration of a batch.
#[derive(Clone, Copy, Debug)]
pub struct BatchItem<'a> {
    pub frames: &'a [HumanFrame],
    pub registration: &'a RegistrationSpec,
}

/// Batch mapping was cancelled through its flag.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("mapping cancelled after {completed} of {total} demonstrations")]
pub struct Cancelled {
    pub completed: usize,
    pub total: usize,
}

/// Maps many demonstrations across `threads` workers (each with its own [`Mapper`]), in input
/// order. `progress(done, total)` is called after each demonstration; `cancel` is polled between
/// demonstrations and between frames of one.
///
/// The batch is mapped consistently: first, on the calling thread, every demonstration's
/// first-frame posture ([`batch_starts`]: one posture branch, each first frame solved from the
/// nearest already-solved one); then every demonstration, in parallel, continues from its own
/// ([`Mapper::map_from`]). So each result depends on the batch, never on scheduling.
#[allow(clippy::too_many_arguments)]
pub fn map_batch(
    mm: &MappingModel,
    robot: &RobotAnchor,
    items: &[BatchItem<'_>],
    weights: Weights,
    options: SolverOptions,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
    cancel: &AtomicBool,
) -> Result<Vec<Result<MappedTrajectory, MappingError>>, Cancelled> {
    let total = items.len();
    let starts = match Mapper::new(mm.clone(), weights, options) {
        Ok(mut m) => batch_starts(&mut m, robot, items, cancel),
        // Reported per item by the workers below.
        Err(_) => Some(vec![None; total]),
    };
    let Some(starts) = starts else {
        return Err(Cancelled {
            completed: 0,
            total,
        });
    };
    let done = AtomicUsize::new(0);
    let results: Vec<Option<Result<MappedTrajectory, MappingError>>> = crate::parallel::map_indexed(
        total,
        threads,
        || Mapper::new(mm.clone(), weights, options),
        |mapper, i| {
            let mapper = match mapper {
                Ok(m) => m,
                // Configuration errors apply to every item; report them all.
                Err(e) => return Some(Err(e.clone())),
            };
            if cancel.load(Ordering::Relaxed) {
                return None;
            }
            let item = items[i];
            let r = mapper.map_cancellable(
                item.frames,
                item.registration,
                robot,
                starts[i].as_ref(),
                cancel,
            )?;
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d, total);
            Some(r)
        },
    );
    if cancel.load(Ordering::Relaxed) || results.iter().any(Option::is_none) {
        return Err(Cancelled {
            completed: done.load(Ordering::Relaxed),
            total,
        });
    }
    Ok(results
        .into_iter()
        .map(|r| r.expect("checked above"))
        .collect())
}
