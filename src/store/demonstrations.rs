//! The `demonstrations` table (migration 0003).

use sqlx::{SqliteConnection, SqlitePool};

use crate::human::{Demonstration, FRAME_WIDTH, IngestSummary, ObjectSpec, Subject, pack_frames};
use crate::store::blob;

/// A stored demonstration without its frames.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct DemonstrationRow {
    pub id: String,
    pub external_id: Option<String>,
    pub job_id: Option<String>,
    pub subject_id: String,
    pub object_name: String,
    pub task: String,
    pub position_index: i64,
    pub trial: i64,
    pub synthetic: bool,
    pub subject: String,
    pub object: String,
    pub summary: String,
    pub frame_count: i64,
    pub created_at: String,
}

impl DemonstrationRow {
    fn decode<T: serde::de::DeserializeOwned>(
        &self,
        what: &str,
        text: &str,
    ) -> Result<T, sqlx::Error> {
        serde_json::from_str(text).map_err(|e| {
            sqlx::Error::Decode(format!("demonstrations.{what} of {}: {e}", self.id).into())
        })
    }
    pub fn subject(&self) -> Result<Subject, sqlx::Error> {
        self.decode("subject", &self.subject)
    }
    pub fn object(&self) -> Result<ObjectSpec, sqlx::Error> {
        self.decode("object", &self.object)
    }
    pub fn summary(&self) -> Result<IngestSummary, sqlx::Error> {
        self.decode("summary", &self.summary)
    }
}

macro_rules! columns {
    () => {
        "id, external_id, job_id, subject_id, object_name, task, position_index, trial, \
         synthetic, subject, object, summary, frame_count, created_at"
    };
}

/// Filter and page for [`list`].
#[derive(Debug, Clone, Default)]
pub struct DemonstrationFilter {
    pub subject: Option<String>,
    pub object: Option<String>,
    pub synthetic: Option<bool>,
    pub job_id: Option<String>,
    pub limit: u32,
    pub offset: u32,
}

/// Insert one ingested demonstration with id `id` (inside the caller's transaction).
pub async fn insert(
    conn: &mut SqliteConnection,
    id: &str,
    job_id: Option<&str>,
    demo: &Demonstration,
    created_at: &str,
) -> Result<(), sqlx::Error> {
    let flat = pack_frames(&demo.frames, &demo.glove);
    let frames = blob::encode(&[demo.frames.len(), FRAME_WIDTH], &flat)
        .map_err(|e| sqlx::Error::Encode(e.to_string().into()))?;
    sqlx::query(concat!(
        "INSERT INTO demonstrations (",
        columns!(),
        ", frames) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)"
    ))
    .bind(id)
    .bind(demo.labels.external_id.as_deref())
    .bind(job_id)
    .bind(&demo.subject.id)
    .bind(&demo.object.name)
    .bind(&demo.labels.task)
    .bind(i64::from(demo.labels.position_index))
    .bind(i64::from(demo.labels.trial))
    .bind(demo.labels.synthetic)
    .bind(json(&demo.subject))
    .bind(json(&demo.object))
    .bind(json(&demo.summary))
    .bind(demo.frames.len() as i64)
    .bind(created_at)
    .bind(frames)
    .execute(conn)
    .await?;
    Ok(())
}

/// Small metadata documents are plain data; serialising them cannot fail.
fn json<T: serde::Serialize>(v: &T) -> String {
    serde_json::to_string(v).expect("plain data serialises")
}

pub async fn get(pool: &SqlitePool, id: &str) -> Result<Option<DemonstrationRow>, sqlx::Error> {
    sqlx::query_as::<_, DemonstrationRow>(concat!(
        "SELECT ",
        columns!(),
        " FROM demonstrations WHERE id = ?"
    ))
    .bind(id)
    .fetch_optional(pool)
    .await
}

pub async fn get_by_external_id(
    conn: &mut SqliteConnection,
    external_id: &str,
) -> Result<Option<DemonstrationRow>, sqlx::Error> {
    sqlx::query_as::<_, DemonstrationRow>(concat!(
        "SELECT ",
        columns!(),
        " FROM demonstrations WHERE external_id = ?"
    ))
    .bind(external_id)
    .fetch_optional(conn)
    .await
}

/// Demonstrations matching `filter`, newest first, and the number matching without the page.
pub async fn list(
    pool: &SqlitePool,
    f: &DemonstrationFilter,
) -> Result<(Vec<DemonstrationRow>, i64), sqlx::Error> {
    // A macro rather than a const so the queries stay `&'static str` literals via `concat!`.
    macro_rules! filter {
        () => {
            " WHERE (?1 IS NULL OR subject_id = ?1) AND (?2 IS NULL OR object_name = ?2) \
             AND (?3 IS NULL OR synthetic = ?3) AND (?4 IS NULL OR job_id = ?4)"
        };
    }
    let rows = sqlx::query_as::<_, DemonstrationRow>(concat!(
        "SELECT ",
        columns!(),
        " FROM demonstrations",
        filter!(),
        " ORDER BY created_at DESC, rowid LIMIT ?5 OFFSET ?6"
    ))
    .bind(f.subject.as_deref())
    .bind(f.object.as_deref())
    .bind(f.synthetic)
    .bind(f.job_id.as_deref())
    .bind(i64::from(f.limit))
    .bind(i64::from(f.offset))
    .fetch_all(pool)
    .await?;
    let total: i64 = sqlx::query_scalar(concat!("SELECT COUNT(*) FROM demonstrations", filter!()))
        .bind(f.subject.as_deref())
        .bind(f.object.as_deref())
        .bind(f.synthetic)
        .bind(f.job_id.as_deref())
        .fetch_one(pool)
        .await?;
    Ok((rows, total))
}

/// Ids of the demonstrations whose external id starts with `prefix` (a synthetic study's rows:
/// `synth-<seed>-…`), in external-id order.
pub async fn ids_by_external_prefix(
    pool: &SqlitePool,
    prefix: &str,
) -> Result<Vec<String>, sqlx::Error> {
    // `substr` rather than LIKE: external ids may contain `%` and `_`.
    sqlx::query_scalar(
        "SELECT id FROM demonstrations WHERE substr(external_id, 1, length(?1)) = ?1 \
         ORDER BY external_id",
    )
    .bind(prefix)
    .fetch_all(pool)
    .await
}

/// The encoded frame BLOB of a demonstration.
pub async fn frames(pool: &SqlitePool, id: &str) -> Result<Option<Vec<u8>>, sqlx::Error> {
    sqlx::query_scalar("SELECT frames FROM demonstrations WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await
}

/// Ids of the mappings that use demonstration `id`.
///
/// The `mappings` table belongs to migration 0005, which may not exist yet; until it does nothing
/// can use a demonstration. Once it does, a mapping refers to its demonstration either through a
/// `mappings.demonstration_id` column or through a link table
/// `mapping_demonstrations(mapping_id, demonstration_id)`; both are recognised, so the check needs
/// no change when 0005 lands.
pub async fn mappings_using(
    conn: &mut SqliteConnection,
    id: &str,
) -> Result<Vec<String>, sqlx::Error> {
    let has_column: bool = sqlx::query_scalar(
        "SELECT EXISTS (SELECT 1 FROM pragma_table_info('mappings') WHERE name = 'demonstration_id')",
    )
    .fetch_one(&mut *conn)
    .await?;
    let mut ids: Vec<String> = Vec::new();
    if has_column {
        ids.extend(
            sqlx::query_scalar::<_, String>("SELECT id FROM mappings WHERE demonstration_id = ?")
                .bind(id)
                .fetch_all(&mut *conn)
                .await?,
        );
    }
    let has_link: bool = sqlx::query_scalar(
        "SELECT EXISTS (SELECT 1 FROM pragma_table_info('mapping_demonstrations') \
         WHERE name = 'demonstration_id')",
    )
    .fetch_one(&mut *conn)
    .await?;
    if has_link {
        ids.extend(
            sqlx::query_scalar::<_, String>(
                "SELECT mapping_id FROM mapping_demonstrations WHERE demonstration_id = ?",
            )
            .bind(id)
            .fetch_all(&mut *conn)
            .await?,
        );
    }
    ids.sort();
    ids.dedup();
    Ok(ids)
}

/// Outcome of [`delete`].
#[derive(Debug, PartialEq, Eq)]
pub enum Deleted {
    Yes {
        mappings_deleted: usize,
    },
    NotFound,
    /// Mappings use the demonstration and no cascade was asked for.
    InUse {
        mappings: Vec<String>,
    },
}

/// Delete a demonstration; with `cascade`, also the mappings that use it (one transaction).
pub async fn delete(pool: &SqlitePool, id: &str, cascade: bool) -> Result<Deleted, sqlx::Error> {
    let mut tx = super::begin_write(pool).await?;
    let exists: bool =
        sqlx::query_scalar("SELECT EXISTS (SELECT 1 FROM demonstrations WHERE id = ?)")
            .bind(id)
            .fetch_one(&mut **tx)
            .await?;
    if !exists {
        return Ok(Deleted::NotFound);
    }
    let mappings = mappings_using(&mut tx, id).await?;
    if !mappings.is_empty() && !cascade {
        return Ok(Deleted::InUse { mappings });
    }
    let has_link: bool = sqlx::query_scalar(
        "SELECT EXISTS (SELECT 1 FROM sqlite_master WHERE type = 'table' \
         AND name = 'mapping_demonstrations')",
    )
    .fetch_one(&mut **tx)
    .await?;
    for m in &mappings {
        if has_link {
            sqlx::query("DELETE FROM mapping_demonstrations WHERE mapping_id = ?")
                .bind(m)
                .execute(&mut **tx)
                .await?;
        }
        sqlx::query("DELETE FROM mappings WHERE id = ?")
            .bind(m)
            .execute(&mut **tx)
            .await?;
    }
    sqlx::query("DELETE FROM demonstrations WHERE id = ?")
        .bind(id)
        .execute(&mut **tx)
        .await?;
    tx.commit().await?;
    Ok(Deleted::Yes {
        mappings_deleted: mappings.len(),
    })
}
