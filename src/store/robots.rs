//! The robots table: arm-hand systems as descriptor JSON plus URDF text(s).

use sqlx::SqlitePool;

use super::now;

#[derive(Debug, Clone, PartialEq, sqlx::FromRow)]
pub struct RobotRow {
    pub id: String,
    pub name: String,
    pub bundled: bool,
    pub descriptor: String,
    pub arm_urdf: String,
    pub hand_urdf: Option<String>,
    pub created_at: String,
    pub updated_at: String,
}

/// What to store for a system (timestamps are set here).
#[derive(Debug, Clone)]
pub struct NewRobot<'a> {
    pub id: &'a str,
    pub name: &'a str,
    pub bundled: bool,
    pub descriptor: &'a str,
    pub arm_urdf: &'a str,
    pub hand_urdf: Option<&'a str>,
}

pub async fn get(pool: &SqlitePool, id: &str) -> Result<Option<RobotRow>, sqlx::Error> {
    sqlx::query_as("SELECT id, name, bundled, descriptor, arm_urdf, hand_urdf, created_at, updated_at FROM robots WHERE id = ?")
        .bind(id)
        .fetch_optional(pool)
        .await
}

pub async fn list(pool: &SqlitePool) -> Result<Vec<RobotRow>, sqlx::Error> {
    sqlx::query_as("SELECT id, name, bundled, descriptor, arm_urdf, hand_urdf, created_at, updated_at FROM robots ORDER BY bundled DESC, created_at, id")
        .fetch_all(pool)
        .await
}

pub async fn insert(pool: &SqlitePool, r: &NewRobot<'_>) -> Result<RobotRow, sqlx::Error> {
    insert_with_meshes(pool, r, &[]).await
}

/// Inserts a registered system with the collision meshes its URDF references (filename as the
/// URDF writes it, file bytes), in one transaction.
pub async fn insert_with_meshes(
    pool: &SqlitePool,
    r: &NewRobot<'_>,
    meshes: &[(String, Vec<u8>)],
) -> Result<RobotRow, sqlx::Error> {
    let t = now();
    let mut tx = super::begin_write(pool).await?;
    sqlx::query(
        "INSERT INTO robots (id, name, bundled, descriptor, arm_urdf, hand_urdf, created_at, updated_at) \
         VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
    )
    .bind(r.id)
    .bind(r.name)
    .bind(r.bundled)
    .bind(r.descriptor)
    .bind(r.arm_urdf)
    .bind(r.hand_urdf)
    .bind(&t)
    .bind(&t)
    .execute(&mut *tx)
    .await?;
    for (filename, data) in meshes {
        sqlx::query("INSERT INTO robot_meshes (robot_id, filename, data) VALUES (?, ?, ?)")
            .bind(r.id)
            .bind(filename)
            .bind(data)
            .execute(&mut *tx)
            .await?;
    }
    tx.commit().await?;
    Ok(RobotRow {
        id: r.id.to_owned(),
        name: r.name.to_owned(),
        bundled: r.bundled,
        descriptor: r.descriptor.to_owned(),
        arm_urdf: r.arm_urdf.to_owned(),
        hand_urdf: r.hand_urdf.map(str::to_owned),
        created_at: t.clone(),
        updated_at: t,
    })
}

/// What a bundled sync did with one system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Upsert {
    Inserted,
    Updated,
    Unchanged,
}

/// Inserts a bundled system, updates it when any stored text differs, or leaves it alone; in one
/// transaction so concurrent starts cannot interleave.
pub async fn upsert_bundled(pool: &SqlitePool, r: &NewRobot<'_>) -> Result<Upsert, sqlx::Error> {
    let mut tx = super::begin_write(pool).await?;
    let existing: Option<RobotRow> = sqlx::query_as("SELECT id, name, bundled, descriptor, arm_urdf, hand_urdf, created_at, updated_at FROM robots WHERE id = ?")
        .bind(r.id)
        .fetch_optional(&mut *tx)
        .await?;
    let t = now();
    let outcome = match existing {
        None => {
            sqlx::query(
                "INSERT INTO robots (id, name, bundled, descriptor, arm_urdf, hand_urdf, created_at, updated_at) \
                 VALUES (?, ?, 1, ?, ?, ?, ?, ?)",
            )
            .bind(r.id)
            .bind(r.name)
            .bind(r.descriptor)
            .bind(r.arm_urdf)
            .bind(r.hand_urdf)
            .bind(&t)
            .bind(&t)
            .execute(&mut *tx)
            .await?;
            Upsert::Inserted
        }
        Some(e)
            if e.bundled
                && e.name == r.name
                && e.descriptor == r.descriptor
                && e.arm_urdf == r.arm_urdf
                && e.hand_urdf.as_deref() == r.hand_urdf =>
        {
            Upsert::Unchanged
        }
        Some(_) => {
            sqlx::query(
                "UPDATE robots SET name = ?, bundled = 1, descriptor = ?, arm_urdf = ?, hand_urdf = ?, updated_at = ? \
                 WHERE id = ?",
            )
            .bind(r.name)
            .bind(r.descriptor)
            .bind(r.arm_urdf)
            .bind(r.hand_urdf)
            .bind(&t)
            .bind(r.id)
            .execute(&mut *tx)
            .await?;
            Upsert::Updated
        }
    };
    tx.commit().await?;
    Ok(outcome)
}

/// Deletes a registered system; `Ok(false)` when it does not exist. A foreign-key violation
/// (the system is referenced) comes back as the sqlx error.
pub async fn delete(pool: &SqlitePool, id: &str) -> Result<bool, sqlx::Error> {
    let done = sqlx::query("DELETE FROM robots WHERE id = ? AND bundled = 0")
        .bind(id)
        .execute(pool)
        .await?;
    Ok(done.rows_affected() > 0)
}

/// One mesh uploaded with system `id`, by its URDF filename.
pub async fn mesh(
    pool: &SqlitePool,
    id: &str,
    filename: &str,
) -> Result<Option<Vec<u8>>, sqlx::Error> {
    sqlx::query_scalar("SELECT data FROM robot_meshes WHERE robot_id = ? AND filename = ?")
        .bind(id)
        .bind(filename)
        .fetch_optional(pool)
        .await
}

/// The meshes uploaded with a registered system (none for bundled ones), by URDF filename.
pub async fn meshes(pool: &SqlitePool, id: &str) -> Result<Vec<(String, Vec<u8>)>, sqlx::Error> {
    sqlx::query_as("SELECT filename, data FROM robot_meshes WHERE robot_id = ? ORDER BY filename")
        .bind(id)
        .fetch_all(pool)
        .await
}
