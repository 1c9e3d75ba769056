//! The robot library: every arm-hand system the service knows (bundled from `robots/`, or
//! registered through the API), loaded from its stored row and cached until the row changes.
//! This is the one place that turns a robot id into a [`System`]; services, the bridge, the
//! dashboard and the CLI all resolve robots here.

use std::collections::HashMap;
use std::path::Path as FsPath;
use std::sync::{Arc, RwLock};

use sqlx::SqlitePool;

use super::robots as repo;
use crate::kinematics::{
    self, KinematicsError, MapMeshes, NoMeshes, System, SystemDescriptor, UrdfSources,
};

/// Why a robot id did not resolve to a system.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LibraryError {
    /// No robot has this id.
    #[error("unknown robot '{0}'")]
    UnknownRobot(String),
    #[error(transparent)]
    Store(#[from] sqlx::Error),
    /// A stored row that was valid when written no longer loads: a bug, not bad input.
    #[error("stored robot {id} no longer loads: {reason}")]
    Broken { id: String, reason: String },
}

/// Loaded systems by id, rebuilt when the stored row changes (keyed by `updated_at`); cheap to
/// clone.
#[derive(Clone, Debug)]
pub struct RobotLibrary {
    db: SqlitePool,
    cache: Arc<RwLock<HashMap<String, CachedSystem>>>,
}

/// `(updated_at of the row it was built from, the system)`.
type CachedSystem = (String, Arc<System>);

impl RobotLibrary {
    pub fn new(db: SqlitePool) -> Self {
        RobotLibrary {
            db,
            cache: Arc::default(),
        }
    }

    /// The loaded system `id`, bundled or registered ([`LibraryError::UnknownRobot`] if none).
    pub async fn system(&self, id: &str) -> Result<Arc<System>, LibraryError> {
        let row = repo::get(&self.db, id)
            .await?
            .ok_or_else(|| LibraryError::UnknownRobot(id.to_owned()))?;
        self.load_cached(row).await
    }

    /// Keeps a system just built from its row (a registration) so that it is not rebuilt.
    pub fn remember(&self, id: &str, updated_at: &str, system: Arc<System>) {
        self.cache
            .write()
            .expect("robot cache lock")
            .insert(id.to_owned(), (updated_at.to_owned(), system));
    }

    /// Drops a deleted robot's system.
    pub fn forget(&self, id: &str) {
        self.cache.write().expect("robot cache lock").remove(id);
    }

    /// The system of a row already read (a listing reads every row once).
    pub async fn load_cached(&self, row: repo::RobotRow) -> Result<Arc<System>, LibraryError> {
        if let Some((stamp, s)) = self.cache.read().expect("robot cache lock").get(&row.id)
            && *stamp == row.updated_at
        {
            return Ok(s.clone());
        }
        let meshes = if row.bundled {
            Default::default()
        } else {
            repo::meshes(&self.db, &row.id).await?.into_iter().collect()
        };
        let (id, stamp) = (row.id.clone(), row.updated_at.clone());
        let broken = |reason: String| LibraryError::Broken {
            id: id.clone(),
            reason,
        };
        let built =
            tokio::task::spawn_blocking(move || system_from_stored(&row, &MapMeshes(meshes)))
                .await
                .map_err(|e| broken(e.to_string()))?
                .map_err(|e| broken(e.to_string()))?;
        let s = Arc::new(built);
        self.cache
            .write()
            .expect("robot cache lock")
            .insert(id, (stamp, s.clone()));
        Ok(s)
    }
}

/// Builds the system of a stored row (URDF texts + descriptor; meshes are not stored, so
/// registered systems use primitives).
pub fn system_from_row(row: &repo::RobotRow) -> Result<System, KinematicsError> {
    system_from_stored(row, &NoMeshes)
}

/// [`system_from_row`] with the meshes uploaded with the system.
pub fn system_from_stored(
    row: &repo::RobotRow,
    meshes: &dyn kinematics::MeshSource,
) -> Result<System, KinematicsError> {
    let desc: SystemDescriptor =
        serde_json::from_str(&row.descriptor).map_err(|e| KinematicsError::Descriptor {
            field: "descriptor".into(),
            reason: e.to_string(),
        })?;
    match &row.hand_urdf {
        Some(hand) => System::from_sources(
            desc,
            UrdfSources::ArmAndHand {
                arm: &row.arm_urdf,
                hand,
            },
            meshes,
        ),
        None => System::from_sources(desc, UrdfSources::Combined(&row.arm_urdf), meshes),
    }
}

/// Synchronises `robots/systems/*.toml` into the database at start: new files are inserted,
/// changed ones updated, unchanged ones left alone. A file that does not load is logged and
/// skipped (the service still starts).
pub async fn sync_bundled(db: &SqlitePool, robots_dir: &FsPath) -> anyhow::Result<()> {
    let dir = robots_dir.join("systems");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        tracing::warn!(dir = %dir.display(), "no bundled systems folder");
        return Ok(());
    };
    let mut files: Vec<_> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    files.sort();
    for path in files {
        let Some(id) = path.file_stem().and_then(|s| s.to_str()).map(str::to_owned) else {
            continue;
        };
        let loaded = tokio::task::spawn_blocking({
            let path = path.clone();
            move || bundled_texts(&path)
        })
        .await?;
        let (desc, arm, hand) = match loaded {
            Ok(t) => t,
            Err(e) => {
                tracing::warn!(file = %path.display(), error = %e, "bundled system does not load; skipped");
                continue;
            }
        };
        let descriptor = serde_json::to_string(&desc)?;
        let outcome = repo::upsert_bundled(
            db,
            &repo::NewRobot {
                id: &id,
                name: &desc.name,
                bundled: true,
                descriptor: &descriptor,
                arm_urdf: &arm,
                hand_urdf: hand.as_deref(),
            },
        )
        .await?;
        tracing::info!(robot = %id, ?outcome, "bundled system");
    }
    Ok(())
}

/// Loads a bundled descriptor file, checks it builds from its texts alone, returns the texts.
fn bundled_texts(
    path: &FsPath,
) -> Result<(SystemDescriptor, String, Option<String>), KinematicsError> {
    let system = System::from_file(path)?;
    let desc = system.descriptor.clone();
    let dir = path.parent().unwrap_or(FsPath::new("."));
    let read = |rel: &str| {
        std::fs::read_to_string(dir.join(rel)).map_err(|e| KinematicsError::FileUnreadable {
            path: dir.join(rel).display().to_string(),
            reason: e.to_string(),
        })
    };
    let (arm, hand) = match (&desc.arm_urdf, &desc.hand_urdf, &desc.urdf) {
        (Some(a), Some(h), _) => (read(a)?, Some(read(h)?)),
        (_, _, Some(c)) => (read(c)?, None),
        _ => unreachable!("System::from_file checked the URDF fields"),
    };
    let row = repo::RobotRow {
        id: String::new(),
        name: desc.name.clone(),
        bundled: true,
        descriptor: serde_json::to_string(&desc).expect("descriptor serialises"),
        arm_urdf: arm.clone(),
        hand_urdf: hand.clone(),
        created_at: String::new(),
        updated_at: String::new(),
    };
    system_from_row(&row)?;
    Ok((desc, arm, hand))
}

/// Resolves `--robot`: a descriptor file path, a bundled id (`robots/systems/<id>.toml`), or a
/// registered id in the database.
pub fn resolve_for_cli(robots_dir: &FsPath, db: &FsPath, robot: &str) -> anyhow::Result<System> {
    let as_path = FsPath::new(robot);
    if as_path.is_file() {
        return Ok(System::from_file(as_path)?);
    }
    let bundled = robots_dir.join("systems").join(format!("{robot}.toml"));
    if bundled.is_file() {
        return Ok(System::from_file(&bundled)?);
    }
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let row = runtime.block_on(async {
        let db = super::connect(db).await?;
        let row = repo::get(&db, robot).await?;
        db.close().await;
        anyhow::Ok(row)
    })?;
    let row = row.ok_or_else(|| {
        anyhow::anyhow!(
            "robot '{robot}' is neither a descriptor file, a bundled id nor a registered id"
        )
    })?;
    Ok(system_from_row(&row)?)
}
