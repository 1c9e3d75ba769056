//! What first-start seeding (`crate::seed`) is preparing, as the use cases see it: a request
//! that needs a default model still being trained answers "not ready" with the job to watch.

use std::collections::HashMap;
use std::sync::{Arc, RwLock};

use uuid::Uuid;

/// Robots whose default model the seeding is preparing, with the job to watch.
#[derive(Clone, Debug, Default)]
pub struct SeedStatus(Arc<RwLock<HashMap<String, Uuid>>>);

impl SeedStatus {
    /// The job to watch while `robot`'s default model is being prepared, if it is.
    pub fn pending_job(&self, robot: &str) -> Option<Uuid> {
        self.0.read().expect("seed status lock").get(robot).copied()
    }

    pub fn set(&self, robot: &str, job: Uuid) {
        self.0
            .write()
            .expect("seed status lock")
            .insert(robot.to_owned(), job);
    }

    pub fn clear(&self, robot: &str) {
        self.0.write().expect("seed status lock").remove(robot);
    }
}
