//! The measured state history of executions (migration 0010): the [`Recorder`] the bridge hub
//! feeds with every feedback message of a running execution (decimated and bounded, in memory),
//! and the append-only chunk table it is flushed to.
//!
//! Decimation: time is cut into bins of [`Recorder::interval`] seconds (initially
//! `1 / MAX_RATE_HZ`) and the first sample of each bin is kept, so the kept rate never exceeds
//! [`MAX_RATE_HZ`] whatever the worker sends. Bound: when [`MAX_SAMPLES`] are kept, every other
//! one is dropped and the bin width doubles; the history always spans the whole execution and
//! never holds more than `MAX_SAMPLES` rows (plus the final sample, see [`Recorder::close`]).
//!
//! Row layout (`data`, row-major, [`width`] values per row): `t`, `progress`, `tracking_error`,
//! the `n` measured positions, the `n` measured velocities.

use sqlx::{SqliteConnection, SqlitePool};

use super::blob;

/// Most samples kept per second of execution.
pub const MAX_RATE_HZ: f64 = 20.0;
/// Most samples kept per execution (a halving happens when this many are held).
pub const MAX_SAMPLES: usize = 4000;

/// Values per stored row for `n` joints.
pub const fn width(n_joints: usize) -> usize {
    3 + 2 * n_joints
}

/// One stored sample, borrowed from a [`History`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample<'a> {
    pub t: f64,
    pub progress: f64,
    pub tracking_error: f64,
    pub positions: &'a [f64],
    pub velocities: &'a [f64],
}

/// A feedback history: rows of [`width`]`(n_joints)` values, strictly increasing `t`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct History {
    pub n_joints: usize,
    pub data: Vec<f64>,
}

impl History {
    pub fn len(&self) -> usize {
        self.data.len() / width(self.n_joints)
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    pub fn sample(&self, i: usize) -> Sample<'_> {
        let w = width(self.n_joints);
        let n = self.n_joints;
        let r = &self.data[i * w..(i + 1) * w];
        Sample {
            t: r[0],
            progress: r[1],
            tracking_error: r[2],
            positions: &r[3..3 + n],
            velocities: &r[3 + n..],
        }
    }

    pub fn samples(&self) -> impl ExactSizeIterator<Item = Sample<'_>> + '_ {
        (0..self.len()).map(|i| self.sample(i))
    }

    /// Index of the first sample with `t > since`.
    pub fn first_after(&self, since: f64) -> usize {
        let (mut lo, mut hi) = (0, self.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.sample(mid).t > since {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        lo
    }
}

/// What a flush writes: the rows not stored yet as a new chunk, or (after a halving) the whole
/// history replacing the stored chunks.
#[derive(Debug, Clone, PartialEq)]
pub struct Chunk {
    /// Delete the stored chunks first.
    pub replace: bool,
    /// The chunk number to insert.
    pub index: i64,
    pub samples: usize,
    pub bytes: Vec<u8>,
    /// Rows of the recorder stored once this chunk is written.
    upto: usize,
    generation: u64,
}

/// The decimated, bounded history of one running execution, and how much of it is stored.
#[derive(Debug, Clone)]
pub struct Recorder {
    n: usize,
    data: Vec<f64>,
    interval: f64,
    last_bin: i64,
    last_seen: f64,
    /// The newest sample when it was not kept (its bin already had one): the final state.
    latest: Vec<f64>,
    latest_pending: bool,
    stored_rows: usize,
    stored_chunks: i64,
    /// The stored chunks are stale (a halving happened since): the next flush replaces them.
    rewrite: bool,
    generation: u64,
}

impl Recorder {
    pub fn new(n_joints: usize) -> Recorder {
        let w = width(n_joints);
        Recorder {
            n: n_joints,
            // A typical execution (seconds long) never reallocates.
            data: Vec::with_capacity(w * 256),
            interval: 1.0 / MAX_RATE_HZ,
            last_bin: i64::MIN,
            last_seen: f64::NEG_INFINITY,
            latest: vec![0.0; w],
            latest_pending: false,
            stored_rows: 0,
            stored_chunks: 0,
            rewrite: false,
            generation: 0,
        }
    }

    pub fn n_joints(&self) -> usize {
        self.n
    }

    /// Samples kept (stored or not).
    pub fn len(&self) -> usize {
        self.data.len() / width(self.n)
    }

    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// The current bin width (s): at most one kept sample per bin.
    pub fn interval(&self) -> f64 {
        self.interval
    }

    /// Offers one measured state; returns whether it was kept. Samples whose `t` does not
    /// increase, or with the wrong number of values, are ignored.
    pub fn record(
        &mut self,
        t: f64,
        progress: f64,
        tracking_error: f64,
        positions: &[f64],
        velocities: &[f64],
    ) -> bool {
        if !t.is_finite()
            || t <= self.last_seen
            || positions.len() != self.n
            || velocities.len() != self.n
        {
            return false;
        }
        self.last_seen = t;
        let bin = (t / self.interval).floor() as i64;
        if bin <= self.last_bin {
            self.latest[0] = t;
            self.latest[1] = progress;
            self.latest[2] = tracking_error;
            self.latest[3..3 + self.n].copy_from_slice(positions);
            self.latest[3 + self.n..].copy_from_slice(velocities);
            self.latest_pending = true;
            return false;
        }
        self.data.extend_from_slice(&[t, progress, tracking_error]);
        self.data.extend_from_slice(positions);
        self.data.extend_from_slice(velocities);
        self.last_bin = bin;
        self.latest_pending = false;
        if self.len() >= MAX_SAMPLES {
            self.halve();
        }
        true
    }

    /// Keeps every other sample (the first included) and doubles the bin width.
    fn halve(&mut self) {
        let w = width(self.n);
        let rows = self.len();
        let mut keep = 0;
        for r in (0..rows).step_by(2) {
            self.data.copy_within(r * w..(r + 1) * w, keep * w);
            keep += 1;
        }
        self.data.truncate(keep * w);
        self.interval *= 2.0;
        let last_t = self.data[(keep - 1) * w];
        self.last_bin = (last_t / self.interval).floor() as i64;
        self.rewrite = true;
        self.generation += 1;
    }

    /// The execution ended: keeps the newest state too (when decimation had skipped it), so the
    /// history ends where the robot stopped.
    pub fn close(&mut self) {
        if self.latest_pending {
            self.data.extend_from_slice(&self.latest);
            self.latest_pending = false;
        }
    }

    /// The chunk the next flush writes (None: everything is stored).
    pub fn pending(&self) -> Option<Chunk> {
        let w = width(self.n);
        let from = if self.rewrite { 0 } else { self.stored_rows };
        let rows = self.len();
        if rows <= from {
            return None;
        }
        let bytes = blob::encode(&[rows - from, w], &self.data[from * w..])
            .expect("rows of the recorder's width match their shape");
        Some(Chunk {
            replace: self.rewrite,
            index: if self.rewrite { 0 } else { self.stored_chunks },
            samples: rows - from,
            bytes,
            upto: rows,
            generation: self.generation,
        })
    }

    /// Records that `chunk` (from [`Recorder::pending`]) was written.
    pub fn stored(&mut self, chunk: &Chunk) {
        if chunk.generation != self.generation {
            return; // halved meanwhile: the next flush rewrites everything anyway
        }
        self.stored_rows = chunk.upto;
        self.stored_chunks = chunk.index + 1;
        self.rewrite = false;
    }

    /// A copy of the kept samples.
    pub fn history(&self) -> History {
        History {
            n_joints: self.n,
            data: self.data.clone(),
        }
    }
}

/// Writes a chunk inside the caller's transaction.
pub async fn write_chunk(
    conn: &mut SqliteConnection,
    execution_id: &str,
    chunk: &Chunk,
) -> Result<(), sqlx::Error> {
    if chunk.replace {
        sqlx::query("DELETE FROM execution_feedback WHERE execution_id = ?")
            .bind(execution_id)
            .execute(&mut *conn)
            .await?;
    }
    sqlx::query(
        "INSERT INTO execution_feedback (execution_id, chunk, samples, data) VALUES (?, ?, ?, ?)",
    )
    .bind(execution_id)
    .bind(chunk.index)
    .bind(chunk.samples as i64)
    .bind(&chunk.bytes)
    .execute(&mut *conn)
    .await
    .map(|_| ())
}

/// The stored history of an execution (empty when nothing was flushed).
pub async fn load(
    pool: &SqlitePool,
    execution_id: &str,
    n_joints: usize,
) -> Result<History, sqlx::Error> {
    let rows: Vec<(i64, Vec<u8>)> = sqlx::query_as(
        "SELECT samples, data FROM execution_feedback WHERE execution_id = ? ORDER BY chunk",
    )
    .bind(execution_id)
    .fetch_all(pool)
    .await?;
    let w = width(n_joints);
    let total: i64 = rows.iter().map(|r| r.0).sum();
    let mut data = Vec::with_capacity(total.max(0) as usize * w);
    for (samples, bytes) in rows {
        let a = blob::decode::<f64>(&bytes).map_err(|e| sqlx::Error::Decode(Box::new(e)))?;
        if a.shape != [samples as usize, w] {
            return Err(sqlx::Error::Decode(
                format!(
                    "feedback chunk of execution {execution_id} has shape {:?}, expected [{samples}, {w}]",
                    a.shape
                )
                .into(),
            ));
        }
        data.extend_from_slice(&a.data);
    }
    Ok(History { n_joints, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(r: &mut Recorder, t: f64) -> bool {
        let q = [t.sin(), t.cos()];
        r.record(t, (t / 10.0).min(1.0), 0.001, &q, &[t.cos(), -t.sin()])
    }

    fn strictly_increasing(h: &History) -> bool {
        h.samples().zip(h.samples().skip(1)).all(|(a, b)| b.t > a.t)
    }

    #[test]
    fn feedback_at_50_hz_is_kept_at_20_hz_with_the_final_state() {
        let mut r = Recorder::new(2);
        // 50 Hz for 3 s, with the float drift a worker's clock has
        let (mut t, mut end) = (0.0, 0.0);
        let mut offered = 0;
        while t < 3.0 {
            feed(&mut r, t);
            offered += 1;
            end = t;
            t += 0.02 + 1e-7;
        }
        assert_eq!(offered, 150);
        assert_eq!(r.len(), 60, "one sample per 50 ms bin");
        let h = r.history();
        assert!(strictly_increasing(&h));
        assert_eq!(h.sample(0).t, 0.0);
        // a repeated or older time is ignored
        let last = h.sample(h.len() - 1).t;
        assert!(!feed(&mut r, last));
        assert!(!feed(&mut r, 1.0));
        // the final state is kept at the end even though its bin had a sample
        r.close();
        let h = r.history();
        assert_eq!(h.len(), 61);
        assert_eq!(h.sample(60).t, end);
        assert_eq!(h.sample(60).positions, &[end.sin(), end.cos()]);
        assert_eq!(h.sample(60).velocities, &[end.cos(), -end.sin()]);
        assert!(strictly_increasing(&h));
        // wrong joint counts and non-finite times are not recorded
        let mut r = Recorder::new(2);
        assert!(!r.record(0.0, 0.0, 0.0, &[1.0], &[0.0, 0.0]));
        assert!(!r.record(f64::NAN, 0.0, 0.0, &[1.0, 2.0], &[0.0, 0.0]));
        assert!(r.is_empty());
    }

    #[test]
    fn a_long_run_stays_bounded_and_spans_the_whole_run() {
        let mut r = Recorder::new(2);
        // 2 hours of 100 Hz feedback: 720 000 samples offered
        let n = 720_000;
        for k in 0..n {
            feed(&mut r, k as f64 * 0.01);
        }
        r.close();
        let h = r.history();
        assert!(h.len() <= MAX_SAMPLES + 1, "{} samples", h.len());
        assert!(h.len() >= MAX_SAMPLES / 2, "{} samples", h.len());
        assert!(strictly_increasing(&h));
        assert_eq!(h.sample(0).t, 0.0);
        let end = (n - 1) as f64 * 0.01;
        assert!((h.sample(h.len() - 1).t - end).abs() < 1e-9);
        // the spacing is about uniform: no gap wider than two bins
        let widest = h
            .samples()
            .zip(h.samples().skip(1))
            .map(|(a, b)| b.t - a.t)
            .fold(0.0, f64::max);
        assert!(widest <= 2.0 * r.interval() + 0.011, "gap {widest} s");
        assert!(r.interval() > 1.0 / MAX_RATE_HZ);
    }

    #[tokio::test]
    async fn chunks_append_replace_after_a_halving_and_follow_their_execution() {
        let dir = tempfile::tempdir().unwrap();
        let pool = super::super::connect(&dir.path().join("t.db"))
            .await
            .unwrap();
        let p = crate::store::payload::ExecutionPayload::Trajectory {
            trajectory_id: "inline".into(),
            joint_names: vec!["a".into(), "b".into()],
            points: vec![crate::motion::TrajectoryPoint {
                t: 0.0,
                positions: vec![0.0, 0.0],
                velocities: vec![0.0, 0.0],
                accelerations: vec![0.0, 0.0],
            }],
        };
        let row = super::super::executions::insert(
            &pool,
            "wam_ihy",
            crate::store::payload::Mode::OpenLoop,
            &p,
            None,
        )
        .await
        .unwrap();
        let id = row.id.as_str();
        let mut r = Recorder::new(2);
        assert!(r.pending().is_none());
        let (mut k, mut chunks, mut after_rewrite) = (0usize, 0i64, None::<usize>);
        // a flush per 60 feedback messages (50 Hz) until a halving has been flushed and
        // followed by a few appends
        while after_rewrite.is_none_or(|n| n < 5) {
            for _ in 0..60 {
                feed(&mut r, k as f64 * 0.02);
                k += 1;
            }
            let c = r.pending().expect("new samples are pending");
            let mut tx = pool.begin().await.unwrap();
            write_chunk(&mut tx, id, &c).await.unwrap();
            tx.commit().await.unwrap();
            r.stored(&c);
            chunks = if c.replace { 1 } else { chunks + 1 };
            after_rewrite = match (c.replace, after_rewrite) {
                (true, _) => Some(0),
                (false, Some(n)) => Some(n + 1),
                (false, None) => None,
            };
            assert!(r.pending().is_none());
        }
        r.close();
        if let Some(c) = r.pending() {
            let mut tx = pool.begin().await.unwrap();
            write_chunk(&mut tx, id, &c).await.unwrap();
            tx.commit().await.unwrap();
            r.stored(&c);
            chunks += 1;
        }
        let stored = load(&pool, id, 2).await.unwrap();
        assert_eq!(stored, r.history());
        assert!(stored.len() <= MAX_SAMPLES + 1);
        let (n, total): (i64, i64) = sqlx::query_as(
            "SELECT COUNT(*), SUM(samples) FROM execution_feedback WHERE execution_id = ?",
        )
        .bind(id)
        .fetch_one(&pool)
        .await
        .unwrap();
        assert_eq!((n, total as usize), (chunks, stored.len()));
        assert!(n > 1, "later flushes append chunks after the rewrite");
        assert_eq!(
            super::super::executions::get(&pool, id)
                .await
                .unwrap()
                .unwrap()
                .feedback_samples as usize,
            stored.len()
        );
        // paging helper
        let mid = stored.sample(10).t;
        assert_eq!(stored.first_after(mid), 11);
        assert_eq!(stored.first_after(-1.0), 0);
        assert_eq!(stored.first_after(f64::MAX), stored.len());
        // retention follows the execution
        sqlx::query("DELETE FROM executions WHERE id = ?")
            .bind(id)
            .execute(&pool)
            .await
            .unwrap();
        assert!(load(&pool, id, 2).await.unwrap().is_empty());
    }
}
