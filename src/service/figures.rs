//! The stored data each figure draws, loaded and decoded (the drawing itself is the pure
//! [`crate::figures`]; the edge runs it off the async workers).

use std::sync::Arc;

use super::{Context, Error};
use crate::bridge::ExecutionPayload;
use crate::grasp::{GraspResult, ObjectSpec};
use crate::human::HumanFrame;
use crate::kinematics::System;
use crate::motion::{MotionModel, TrajectoryPoint};
use crate::store::{grasps, mappings, models};

pub use crate::store::mappings::StoredMappedDemo;

use super::executions::{ExecutionRow, History};
use super::grasps::GraspSettings;

/// A demonstration's title (subject, object, position, trial) and its derived frames.
pub async fn demonstration(ctx: &Context, id: &str) -> Result<(String, Vec<HumanFrame>), Error> {
    let (row, frames, _) = super::demonstrations::frames(ctx, id).await?;
    let subject = row.subject()?.id;
    let object = row.object()?.name;
    let title = format!(
        "{subject} reaching for the {object} (position {}, trial {})",
        row.position_index, row.trial
    );
    Ok((title, frames))
}

/// A stored grasp: its robot, object, task settings and result.
#[derive(Debug, Clone)]
pub struct StoredGrasp {
    pub robot: String,
    pub object: ObjectSpec,
    pub settings: GraspSettings,
    pub result: GraspResult,
}

pub async fn grasp(ctx: &Context, id: &str) -> Result<StoredGrasp, Error> {
    let row = grasps::get_grasp(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("grasp", id))?;
    Ok(StoredGrasp {
        object: serde_json::from_str(&row.object).map_err(Error::internal)?,
        settings: serde_json::from_str(&row.request).map_err(Error::internal)?,
        result: serde_json::from_str(&row.result).map_err(Error::internal)?,
        robot: row.robot,
    })
}

/// One demonstration of a succeeded mapping, with the human frames it was mapped from.
pub struct MappedDemoFigure {
    pub system: Arc<System>,
    pub human: Vec<HumanFrame>,
    pub demo: StoredMappedDemo,
}

/// The `index`-th demonstration of a succeeded mapping; `Err(total)` when there is none at
/// `index` (the mapping has `total`).
pub async fn mapping(
    ctx: &Context,
    id: &str,
    index: usize,
) -> Result<Result<MappedDemoFigure, i64>, Error> {
    let row = mappings::get_mapping(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("mapping", id))?;
    if row.status != "succeeded" {
        return Err(Error::Conflict(format!(
            "mapping {id} is {}; its figure exists once it has succeeded",
            row.status
        )));
    }
    let (page, total) = mappings::load_page(&ctx.db, id, None, 1, index as i64).await?;
    let Some((_, demo)) = page.into_iter().next() else {
        return Ok(Err(total));
    };
    let (_, human) = demonstration(ctx, &demo.demonstration_id).await?;
    let system = super::robots::system(ctx, &row.robot).await?;
    Ok(Ok(MappedDemoFigure {
        system,
        human,
        demo,
    }))
}

/// A trained model, its robot and up to `paths` of the demonstrations it learned from.
pub async fn model(
    ctx: &Context,
    id: &str,
    paths: usize,
) -> Result<(String, MotionModel, Vec<StoredMappedDemo>), Error> {
    let row = models::get_model(&ctx.db, id)
        .await?
        .ok_or_else(|| Error::not_found("model", id))?;
    let model = models::load_model(&ctx.db, id).await?.ok_or_else(|| {
        Error::Conflict(format!(
            "model {id} is {}; its figure exists once it is trained",
            row.status
        ))
    })?;
    let request: serde_json::Value = serde_json::from_str(&row.request).map_err(Error::internal)?;
    let mut demos = Vec::new();
    for m in request["mappings"].as_array().into_iter().flatten() {
        if let Some(m) = m.as_str() {
            demos.extend(mappings::load_trajectories(&ctx.db, m).await?);
        }
        if demos.len() >= paths {
            break;
        }
    }
    demos.truncate(paths);
    Ok((row.robot, model, demos))
}

/// An execution, its joint names, what was planned (a closed-loop law's path; empty for a bare
/// law or a stream) and what was measured.
pub async fn execution(
    ctx: &Context,
    id: &str,
) -> Result<(ExecutionRow, Vec<String>, Vec<TrajectoryPoint>, History), Error> {
    let (row, payload, history) = super::executions::with_payload(ctx, id).await?;
    let (joint_names, planned) = match payload {
        ExecutionPayload::Trajectory {
            joint_names,
            points,
            ..
        } => (joint_names, points),
        ExecutionPayload::Model { params, path, .. } => {
            (params.joint_names.clone(), path.unwrap_or_default())
        }
        ExecutionPayload::Stream { joint_names, .. } => (joint_names, Vec::new()),
    };
    Ok((row, joint_names, planned, history))
}
