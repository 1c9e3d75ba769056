//! The crate's one parallel-map facility: index `0..n` mapped across a bounded number of
//! worker threads, each with its own scratch state (a solver's `Data`), answers collected by
//! index. Results never depend on scheduling: item `i`'s answer lands at position `i`, and a
//! worker's scratch must not influence an answer (each item starts from its own inputs).
//!
//! The threads are a [`Pool`]'s. The job runner owns one, sized by the job concurrency, and runs
//! every job inside it, so the parallel maps of all running jobs share those threads and the job
//! limit bounds the CPU they use. A map called outside any pool (the CLI, a synchronous request)
//! gets a pool of its own for the call.

use std::sync::Arc;

use rayon::prelude::*;

/// A fixed set of worker threads for [`map_indexed`].
#[derive(Clone)]
pub struct Pool {
    /// `None` when the threads could not be started: work then runs on the caller's thread.
    threads: Option<Arc<rayon::ThreadPool>>,
}

impl std::fmt::Debug for Pool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pool")
            .field("threads", &self.threads())
            .finish()
    }
}

impl Pool {
    /// A pool of `threads` workers (at least 1).
    pub fn new(threads: usize) -> Pool {
        let built = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(|i| format!("parallel-{i}"))
            .build();
        Pool {
            threads: built.ok().map(Arc::new),
        }
    }

    pub fn threads(&self) -> usize {
        self.threads.as_ref().map_or(1, |p| p.current_num_threads())
    }

    /// Runs `f` on one of the pool's workers (the caller waits); every [`map_indexed`] inside
    /// it shares the pool's threads.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        match &self.threads {
            Some(p) => p.install(f),
            None => f(),
        }
    }
}

/// The threads a parallel map may use here: the current [`Pool`]'s inside one, else the
/// machine's.
pub fn available_threads() -> usize {
    if rayon::current_thread_index().is_some() {
        rayon::current_num_threads()
    } else {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

/// `f(scratch, i)` for every `i` in `0..n`, in index order, on at most `threads` workers:
/// the current [`Pool`]'s when called inside one (at most `threads` items run at once), else
/// a pool built for the call. `init` builds a worker's scratch (possibly more than once per
/// worker).
pub fn map_indexed<S, R, I, F>(n: usize, threads: usize, init: I, f: F) -> Vec<R>
where
    I: Fn() -> S + Sync + Send,
    F: Fn(&mut S, usize) -> R + Sync + Send,
    R: Send,
{
    let threads = threads.clamp(1, n.max(1));
    if threads == 1 {
        let mut scratch = init();
        return (0..n).map(|i| f(&mut scratch, i)).collect();
    }
    if rayon::current_thread_index().is_some() {
        // Inside a pool: pieces of at least n / threads items, so at most `threads` of them.
        return (0..n)
            .into_par_iter()
            .with_min_len(n.div_ceil(threads))
            .map_init(&init, &f)
            .collect();
    }
    // Outside any pool: one for this call, sized by the caller (rayon's global pool would let
    // concurrent callers each use every core).
    Pool::new(threads).install(|| (0..n).into_par_iter().map_init(&init, &f).collect())
}

#[cfg(test)]
mod tests {
    use super::{Pool, available_threads, map_indexed};

    #[test]
    fn answers_land_at_their_index_whatever_the_thread_count() {
        let serial = map_indexed(100, 1, || 0u64, |_, i| i * i);
        for threads in [2, 3, 8] {
            let parallel = map_indexed(100, threads, Vec::<usize>::new, |seen, i| {
                seen.push(i);
                i * i
            });
            assert_eq!(parallel, serial);
        }
        assert!(map_indexed(0, 4, || (), |_, i| i).is_empty());
    }

    #[test]
    fn inside_a_pool_the_answers_are_the_same_and_the_pool_sizes_the_map() {
        let serial = map_indexed(97, 1, || (), |_, i| i * 3);
        for size in [1, 2, 3] {
            let pool = Pool::new(size);
            assert_eq!(pool.threads(), size);
            let (threads, answers) = pool.install(|| {
                (
                    available_threads(),
                    map_indexed(97, 8, Vec::<usize>::new, |seen, i| {
                        seen.push(i);
                        i * 3
                    }),
                )
            });
            assert_eq!(threads, size);
            assert_eq!(answers, serial);
        }
    }
}
