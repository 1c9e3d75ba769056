//! Derived hand kinematics: fingertip poses from the glove's hand angles and the tracker's wrist
//! pose, by forward kinematics of the hand model (the same FK as the robots).

use nalgebra::{Isometry3, Point3};

use super::anthropometry::HandDims;
use super::demo::Handedness;
use super::model::{FINGER_NAMES, HAND_DOF, hand_model};
use crate::kinematics::{Data, FrameId, Model, forward_kinematics};

/// A hand model with its FK scratch, fingertip frames resolved once.
#[derive(Debug, Clone)]
pub struct HandKinematics {
    model: Model,
    data: Data,
    tips: [FrameId; 5],
}

impl HandKinematics {
    pub fn new(dims: &HandDims, handedness: Handedness) -> Self {
        let model = hand_model(dims, handedness);
        debug_assert_eq!(model.nq(), HAND_DOF);
        let data = Data::new(&model);
        let tips = FINGER_NAMES.map(|f| {
            model
                .frame_id(&format!("{f}_tip"))
                .expect("the hand model names every fingertip")
        });
        Self { model, data, tips }
    }

    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Fingertip poses in the wrist frame for hand angles `q` (20 values, glove order).
    pub fn fingertips_local(&mut self, q: &[f64]) -> [Isometry3<f64>; 5] {
        forward_kinematics(&self.model, &mut self.data, q);
        self.tips.map(|id| *self.data.frame(id))
    }

    /// Fingertip poses in the world frame for a wrist placed at `wrist`.
    pub fn fingertips(&mut self, wrist: &Isometry3<f64>, q: &[f64]) -> [Isometry3<f64>; 5] {
        self.fingertips_local(q).map(|p| wrist * p)
    }

    /// The hand model's 21 joint centres in the keypoint order of [`super::KEYPOINT_NAMES`]
    /// (wrist; thumb CMC, MCP, IP, tip; each finger's MCP, PIP, DIP, tip), with the wrist at
    /// `wrist`, for hand angles `q`: the keypoints a perfect hand tracker would report.
    pub fn keypoints(
        &mut self,
        wrist: &Isometry3<f64>,
        q: &[f64],
    ) -> [Point3<f64>; super::KEYPOINT_COUNT] {
        forward_kinematics(&self.model, &mut self.data, q);
        std::array::from_fn(|k| {
            let frame = match k {
                0 => "wrist".to_string(),
                1..=4 => [
                    "thumb_metacarpal",
                    "thumb_proximal",
                    "thumb_distal",
                    "thumb_tip",
                ][k - 1]
                    .to_string(),
                _ => {
                    let finger = FINGER_NAMES[1 + (k - 5) / 4];
                    let segment = ["proximal", "middle", "distal", "tip"][(k - 5) % 4];
                    format!("{finger}_{segment}")
                }
            };
            let id = self
                .model
                .frame_id(&frame)
                .expect("the hand model names every joint centre");
            wrist * Point3::from(self.data.frame(id).translation.vector)
        })
    }

    /// World pose of any frame of the hand model after the last FK call.
    pub fn frame(&self, name: &str) -> Option<Isometry3<f64>> {
        self.model.frame_id(name).map(|id| *self.data.frame(id))
    }
}
