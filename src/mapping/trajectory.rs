//! Mapping whole demonstrations: registration, goals per frame, the frame solver in sequence,
//! and batches across threads.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use super::MappingError;
use super::goals::finger_goals;
use super::objective::{FrameGoals, MappingModel, Weights};
use super::registration::{ArmPoints, Registration, RegistrationSpec, RobotAnchor};
use super::solve::{FrameMetrics, Mapper, SolverOptions, StartReference};
use crate::human::HumanFrame;

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
        let tips: [_; 5] = std::array::from_fn(|i| {
            let iso = &frame.fingertips[i];
            (
                reg.point(&iso.translation.vector.into()),
                reg.orientation(&iso.rotation),
            )
        });
        let mm = self.eval.model();
        finger_goals(&tips, mm.fingers(), mm.thumb, &mut out.fingers);
        out.elbow = reg.point(&frame.elbow);
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
        let m = self.solve_first(&goals, first.t);
        Ok(StartReference {
            q: self.q.clone(),
            objective: m.objective,
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
            let metrics = if k > 0 {
                self.solve_next(&goals, frame.t, frame.t - frames[k - 1].t)
            } else if let Some(r) = reference {
                self.solve_first_from(&goals, frame.t, r)
            } else {
                self.solve_first(&goals, frame.t)
            };
            out.times.push(frame.t);
            out.positions.extend_from_slice(&self.q);
            out.metrics.push(metrics);
        }
        Some(Ok(out))
    }
}

fn check_frame(k: usize, f: &HumanFrame) -> Result<(), MappingError> {
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
    use nalgebra::{Isometry3, Point3, Translation3};
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

/// The reference first-frame posture of a batch: [`Mapper::start_reference`] of the first
/// demonstration whose registration and first frame are valid (`None` if there is none, or once
/// `cancel` is set; the demonstrations then fail or are cancelled on their own).
pub fn batch_reference(
    mapper: &mut Mapper,
    robot: &RobotAnchor,
    items: &[BatchItem<'_>],
    cancel: &AtomicBool,
) -> Option<StartReference> {
    items.iter().find_map(|item| {
        if cancel.load(Ordering::Relaxed) {
            return None;
        }
        mapper
            .start_reference(item.frames, item.registration, robot)
            .ok()
    })
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
/// The batch is mapped consistently: first, on the calling thread, one reference posture
/// ([`batch_reference`]: the multi-start solution of the first valid demonstration's first
/// frame); then every demonstration, in parallel, starts from it ([`Mapper::map_from`]). So the
/// result of each demonstration depends on the batch's first valid one, never on scheduling.
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
    let reference = match Mapper::new(mm.clone(), weights, options) {
        Ok(mut m) => batch_reference(&mut m, robot, items, cancel),
        // Reported per item by the workers below.
        Err(_) => None,
    };
    let reference = reference.as_ref();
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
            let r =
                mapper.map_cancellable(item.frames, item.registration, robot, reference, cancel)?;
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
