//! Registration: human (tracker) frame → robot base frame.
//!
//! A similarity `p_robot = t + s · R · p_human`. Default: the subject's mean shoulder lands on
//! the robot's shoulder centre and the subject's forward and up axes on the robot base's; the
//! uniform scale is `1`, `auto` (robot reach / human reach) or a number. Or an explicit
//! transform (plus scale) from the request.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Unit, UnitQuaternion, Vector3};

use super::MappingError;

/// Uniform scale applied to the human data.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scale {
    /// Keep human dimensions.
    One,
    /// Robot reach / human reach.
    Auto,
    /// A given positive factor.
    Factor(f64),
}

/// Forward and up axes of a body, in the frame its data are expressed in.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BodyAxes {
    pub forward: Vector3<f64>,
    pub up: Vector3<f64>,
}

impl Default for BodyAxes {
    /// Tracker and URDF base convention: x forward, z up.
    fn default() -> Self {
        Self {
            forward: Vector3::x(),
            up: Vector3::z(),
        }
    }
}

/// How to register a demonstration.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RegistrationSpec {
    /// Shoulder onto the robot shoulder centre, subject axes onto robot base axes.
    ShoulderAligned {
        subject_axes: BodyAxes,
        scale: Scale,
    },
    /// `p_robot = transform · (scale · p_human)`.
    Explicit {
        transform: Isometry3<f64>,
        scale: f64,
    },
}

impl Default for RegistrationSpec {
    /// Shoulder-aligned with `auto` scale: the human reach is stretched to the robot's, so the
    /// task lands in the same part of the robot's workspace as it was in the subject's (at scale
    /// 1 a big arm such as the WAM has to fold up next to its own base, far from humanlike).
    fn default() -> Self {
        Self::ShoulderAligned {
            subject_axes: BodyAxes::default(),
            scale: Scale::Auto,
        }
    }
}

/// What the default registration needs to know about the robot, in its base frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotAnchor {
    /// Shoulder centre (where the first arm joint axes meet, or nearly).
    pub shoulder: Point3<f64>,
    /// Base forward and up axes.
    pub axes: BodyAxes,
    /// Largest shoulder-to-fingertip distance the robot reaches.
    pub reach: f64,
}

/// The human arm points registration looks at in one frame (tracker frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ArmPoints {
    pub shoulder: Point3<f64>,
    pub elbow: Point3<f64>,
    pub wrist: Point3<f64>,
    /// Middle fingertip: the end of the human reach.
    pub middle_tip: Point3<f64>,
}

/// A resolved similarity transform `p ↦ t + s R p`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Registration {
    pub rotation: UnitQuaternion<f64>,
    pub translation: Vector3<f64>,
    pub scale: f64,
}

impl Registration {
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// Resolves a spec against a demonstration's arm points and the robot.
    pub fn resolve(
        spec: &RegistrationSpec,
        frames: &[ArmPoints],
        robot: &RobotAnchor,
    ) -> Result<Self, MappingError> {
        if frames.is_empty() {
            return Err(MappingError::EmptyDemonstration);
        }
        for (i, f) in frames.iter().enumerate() {
            for (field, p) in [
                ("shoulder", f.shoulder),
                ("elbow", f.elbow),
                ("wrist", f.wrist),
                ("fingertips[2]", f.middle_tip),
            ] {
                if !p.coords.iter().all(|x| x.is_finite()) {
                    return Err(MappingError::NonFinite { frame: i, field });
                }
            }
        }
        match *spec {
            RegistrationSpec::Explicit { transform, scale } => {
                check_scale(scale)?;
                if !transform.translation.vector.iter().all(|x| x.is_finite())
                    || !transform.rotation.coords.iter().all(|x| x.is_finite())
                {
                    return Err(MappingError::InvalidRegistration {
                        reason: "explicit transform is not finite".into(),
                    });
                }
                Ok(Self {
                    rotation: transform.rotation,
                    translation: transform.translation.vector,
                    scale,
                })
            }
            RegistrationSpec::ShoulderAligned {
                subject_axes,
                scale,
            } => {
                let h = axes_matrix(&subject_axes, "subject")?;
                let r = axes_matrix(&robot.axes, "robot")?;
                let rotation = UnitQuaternion::from_rotation_matrix(
                    &Rotation3::from_matrix_unchecked(r * h.transpose()),
                );
                let n = frames.len() as f64;
                let shoulder = frames
                    .iter()
                    .fold(Vector3::zeros(), |acc, f| acc + f.shoulder.coords)
                    / n;
                let s = match scale {
                    Scale::One => 1.0,
                    Scale::Factor(s) => {
                        check_scale(s)?;
                        s
                    }
                    Scale::Auto => {
                        let human = human_reach(frames)?;
                        if !(robot.reach.is_finite() && robot.reach > 0.0) {
                            return Err(MappingError::InvalidRegistration {
                                reason: format!("robot reach {} is not positive", robot.reach),
                            });
                        }
                        robot.reach / human
                    }
                };
                // p_r = c_r + s R (p_h − c_h)
                let translation = robot.shoulder.coords - rotation * shoulder * s;
                Ok(Self {
                    rotation,
                    translation,
                    scale: s,
                })
            }
        }
    }

    /// A human point in the robot base frame.
    #[inline]
    pub fn point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.rotation * p.coords * self.scale + self.translation)
    }

    /// A human orientation in the robot base frame (scale does not rotate).
    #[inline]
    pub fn orientation(&self, q: &UnitQuaternion<f64>) -> UnitQuaternion<f64> {
        self.rotation * q
    }
}

fn check_scale(s: f64) -> Result<(), MappingError> {
    if s.is_finite() && s > 0.0 {
        Ok(())
    } else {
        Err(MappingError::InvalidScale { value: s })
    }
}

/// Columns: forward, left, up (orthonormalised; up is made orthogonal to forward).
fn axes_matrix(axes: &BodyAxes, which: &'static str) -> Result<Matrix3<f64>, MappingError> {
    let bad = || MappingError::InvalidRegistration {
        reason: format!("{which} forward and up axes must be finite, non-zero and not parallel"),
    };
    if !axes
        .forward
        .iter()
        .chain(axes.up.iter())
        .all(|x| x.is_finite())
    {
        return Err(bad());
    }
    let f = Unit::try_new(axes.forward, 1e-9).ok_or_else(bad)?;
    let u = Unit::try_new(
        axes.up - f.into_inner() * axes.up.dot(&f),
        1e-6 * axes.up.norm(),
    )
    .ok_or_else(bad)?;
    let l = u.cross(&f);
    Ok(Matrix3::from_columns(&[f.into_inner(), l, u.into_inner()]))
}

/// Median over frames of shoulder→elbow + elbow→wrist + wrist→middle tip: the arm's full reach,
/// robust to a few bad samples.
fn human_reach(frames: &[ArmPoints]) -> Result<f64, MappingError> {
    let mut lens: Vec<f64> = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let upper = (f.elbow - f.shoulder).norm();
        let fore = (f.wrist - f.elbow).norm();
        let hand = (f.middle_tip - f.wrist).norm();
        for (segment, length) in [("upper arm", upper), ("forearm", fore), ("hand", hand)] {
            if length < 1e-3 {
                return Err(MappingError::DegenerateArm {
                    frame: i,
                    segment,
                    length,
                });
            }
        }
        lens.push(upper + fore + hand);
    }
    lens.sort_by(f64::total_cmp);
    Ok(lens[lens.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm(shoulder: Point3<f64>) -> ArmPoints {
        ArmPoints {
            shoulder,
            elbow: shoulder + Vector3::new(0.0, 0.0, -0.3),
            wrist: shoulder + Vector3::new(0.25, 0.0, -0.3),
            middle_tip: shoulder + Vector3::new(0.43, 0.0, -0.3),
        }
    }

    fn robot() -> RobotAnchor {
        RobotAnchor {
            shoulder: Point3::new(0.0, 0.0, 0.35),
            axes: BodyAxes::default(),
            reach: 1.46,
        }
    }

    #[test]
    fn default_puts_the_mean_shoulder_on_the_robot_shoulder() {
        let frames = [
            arm(Point3::new(1.0, 2.0, 1.4)),
            arm(Point3::new(1.02, 2.0, 1.42)),
        ];
        let spec = RegistrationSpec::ShoulderAligned {
            subject_axes: BodyAxes::default(),
            scale: Scale::One,
        };
        let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
        let mean = Point3::new(1.01, 2.0, 1.41);
        assert!((reg.point(&mean) - robot().shoulder).norm() < 1e-12);
        // Same axes on both sides: a pure translation.
        assert!(reg.rotation.angle() < 1e-12 && reg.scale == 1.0);
    }

    #[test]
    fn subject_axes_land_on_robot_axes() {
        // Subject faces tracker +y with tracker up +z; robot faces +x.
        let spec = RegistrationSpec::ShoulderAligned {
            subject_axes: BodyAxes {
                forward: Vector3::new(0.0, 2.0, 0.0),
                up: Vector3::new(0.0, 0.3, 1.0), // not orthogonal: orthogonalised against forward
            },
            scale: Scale::Factor(2.0),
        };
        let frames = [arm(Point3::new(0.5, 0.5, 1.5))];
        let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
        let s = frames[0].shoulder;
        let fwd = reg.point(&(s + Vector3::y())) - reg.point(&s);
        let up = reg.point(&(s + Vector3::z())) - reg.point(&s);
        assert!((fwd - Vector3::x() * 2.0).norm() < 1e-12);
        assert!((up - Vector3::z() * 2.0).norm() < 1e-12);
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.3);
        assert!((reg.orientation(&q).angle_to(&(reg.rotation * q))).abs() < 1e-15);
    }

    #[test]
    fn auto_scale_is_robot_reach_over_human_reach() {
        let frames = [arm(Point3::origin()); 3];
        let spec = RegistrationSpec::ShoulderAligned {
            subject_axes: BodyAxes::default(),
            scale: Scale::Auto,
        };
        let reg = Registration::resolve(&spec, &frames, &robot()).unwrap();
        assert!((reg.scale - 1.46 / (0.3 + 0.25 + 0.18)).abs() < 1e-12);
    }

    #[test]
    fn explicit_transform_is_used_as_given() {
        let t = Isometry3::new(Vector3::new(0.1, -0.2, 0.3), Vector3::new(0.0, 0.0, 0.5));
        let spec = RegistrationSpec::Explicit {
            transform: t,
            scale: 0.5,
        };
        let reg = Registration::resolve(&spec, &[arm(Point3::origin())], &robot()).unwrap();
        let p = Point3::new(0.4, 0.1, -0.2);
        assert!((reg.point(&p) - t * Point3::from(p.coords * 0.5)).norm() < 1e-15);
    }

    #[test]
    fn unregistrable_data_is_rejected_with_the_reason() {
        let r = robot();
        let spec = RegistrationSpec::default();
        assert!(matches!(
            Registration::resolve(&spec, &[], &r),
            Err(MappingError::EmptyDemonstration)
        ));
        let mut f = arm(Point3::origin());
        f.elbow.y = f64::NAN;
        assert!(matches!(
            Registration::resolve(&spec, &[arm(Point3::origin()), f], &r),
            Err(MappingError::NonFinite {
                frame: 1,
                field: "elbow"
            })
        ));
        let mut f = arm(Point3::origin());
        f.elbow = f.shoulder;
        let auto = RegistrationSpec::ShoulderAligned {
            subject_axes: BodyAxes::default(),
            scale: Scale::Auto,
        };
        assert!(matches!(
            Registration::resolve(&auto, &[f], &r),
            Err(MappingError::DegenerateArm {
                frame: 0,
                segment: "upper arm",
                ..
            })
        ));
        let parallel = RegistrationSpec::ShoulderAligned {
            subject_axes: BodyAxes {
                forward: Vector3::z(),
                up: Vector3::z() * 3.0,
            },
            scale: Scale::One,
        };
        assert!(matches!(
            Registration::resolve(&parallel, &[arm(Point3::origin())], &r),
            Err(MappingError::InvalidRegistration { .. })
        ));
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let s = RegistrationSpec::ShoulderAligned {
                subject_axes: BodyAxes::default(),
                scale: Scale::Factor(bad),
            };
            assert!(matches!(
                Registration::resolve(&s, &[arm(Point3::origin())], &r),
                Err(MappingError::InvalidScale { .. })
            ));
        }
    }
}
