//! Joint vectors checked once against a model at the edge ("parse, don't validate"), then
//! trusted by the numerics.

use super::error::KinematicsError;
use super::model::Model;

/// Independent joint values in the model's `q` order, all finite and exactly `nq` of them.
#[derive(Clone, Debug, PartialEq)]
pub struct JointVector(Vec<f64>);

fn finite(model: &Model, k: usize, v: f64) -> Result<f64, KinematicsError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(KinematicsError::NonFiniteJointValue {
            joint: model.joint_names()[k].clone(),
            value: v,
        })
    }
}

impl JointVector {
    /// Values already in `q` order.
    pub fn from_slice(model: &Model, values: &[f64]) -> Result<Self, KinematicsError> {
        if values.len() != model.nq() {
            return Err(KinematicsError::WrongLength {
                expected: model.nq(),
                got: values.len(),
            });
        }
        let v = values
            .iter()
            .enumerate()
            .map(|(k, &v)| finite(model, k, v))
            .collect::<Result<_, _>>()?;
        Ok(Self(v))
    }

    /// Values paired with joint names in any order; every independent joint exactly once.
    pub fn from_named(
        model: &Model,
        names: &[impl AsRef<str>],
        values: &[f64],
    ) -> Result<Self, KinematicsError> {
        Self::from_named_with_defaults(model, names, values, None)
    }

    /// Like [`JointVector::from_named`], but joints not named take their value from `defaults`
    /// (in `q` order) when given.
    pub fn from_named_with_defaults(
        model: &Model,
        names: &[impl AsRef<str>],
        values: &[f64],
        defaults: Option<&[f64]>,
    ) -> Result<Self, KinematicsError> {
        if names.len() != values.len() {
            return Err(KinematicsError::WrongLength {
                expected: names.len(),
                got: values.len(),
            });
        }
        if defaults.is_none() && names.len() != model.nq() {
            return Err(KinematicsError::WrongLength {
                expected: model.nq(),
                got: names.len(),
            });
        }
        let mut q = vec![f64::NAN; model.nq()];
        let mut set = vec![false; model.nq()];
        for (name, &v) in names.iter().zip(values) {
            let name = name.as_ref();
            let k = model
                .q_index(name)
                .ok_or_else(|| KinematicsError::UnknownJoint {
                    name: name.to_owned(),
                    known: model.joint_names().join(", "),
                })?;
            if set[k] {
                return Err(KinematicsError::RepeatedJoint {
                    name: name.to_owned(),
                });
            }
            q[k] = finite(model, k, v)?;
            set[k] = true;
        }
        for k in 0..model.nq() {
            if !set[k] {
                match defaults {
                    Some(d) => q[k] = finite(model, k, d[k])?,
                    None => {
                        return Err(KinematicsError::MissingJoint {
                            name: model.joint_names()[k].clone(),
                        });
                    }
                }
            }
        }
        Ok(Self(q))
    }

    pub fn as_slice(&self) -> &[f64] {
        &self.0
    }
    pub fn into_vec(self) -> Vec<f64> {
        self.0
    }
    /// `(name, value)` pairs in `q` order.
    pub fn named<'a>(&'a self, model: &'a Model) -> impl Iterator<Item = (&'a str, f64)> + 'a {
        model
            .joint_names()
            .iter()
            .map(String::as_str)
            .zip(self.0.iter().copied())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::algorithms::tests::planar_2r;

    #[test]
    fn names_set_the_order_and_bad_vectors_name_the_joint() {
        use KinematicsError as E;
        let m = planar_2r(1.0, 1.0);
        assert_eq!(
            JointVector::from_named(&m, &["q2", "q1"], &[2.0, 1.0])
                .unwrap()
                .as_slice(),
            &[1.0, 2.0]
        );
        assert!(matches!(
            JointVector::from_slice(&m, &[1.0]),
            Err(E::WrongLength {
                expected: 2,
                got: 1
            })
        ));
        assert!(
            matches!(JointVector::from_named(&m, &["q1", "qx"], &[1.0, 2.0]), Err(E::UnknownJoint { name, known }) if name == "qx" && known == "q1, q2")
        );
        assert!(
            matches!(JointVector::from_named(&m, &["q1", "q1"], &[1.0, 2.0]), Err(E::RepeatedJoint { name }) if name == "q1")
        );
        assert!(matches!(
            JointVector::from_named(&m, &["q1"], &[1.0]),
            Err(E::WrongLength { .. })
        ));
        assert!(
            matches!(JointVector::from_named(&m, &["q1", "q2"], &[1.0, f64::NAN]), Err(E::NonFiniteJointValue { joint, .. }) if joint == "q2")
        );
        assert!(
            matches!(JointVector::from_slice(&m, &[f64::INFINITY, 0.0]), Err(E::NonFiniteJointValue { joint, .. }) if joint == "q1")
        );
        let partial =
            JointVector::from_named_with_defaults(&m, &["q2"], &[0.5], Some(&[0.1, 0.2])).unwrap();
        assert_eq!(partial.as_slice(), &[0.1, 0.5]);
        assert_eq!(
            partial.named(&m).collect::<Vec<_>>(),
            vec![("q1", 0.1), ("q2", 0.5)]
        );
    }
}
