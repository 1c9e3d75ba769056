//! The crate's one parallel-map facility: index `0..n` mapped across a bounded number of
//! worker threads, each with its own scratch state (a solver's `Data`), answers collected by
//! index. Results never depend on scheduling: item `i`'s answer lands at position `i`, and a
//! worker's scratch must not influence an answer (each item starts from its own inputs).

use rayon::prelude::*;

/// `f(scratch, i)` for every `i` in `0..n`, in index order, on at most `threads` workers;
/// `init` builds a worker's scratch (possibly more than once per worker).
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
    // A pool per call, sized by the caller: the global pool would let concurrent jobs each
    // use every core.
    match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
        Ok(pool) => pool.install(|| (0..n).into_par_iter().map_init(&init, &f).collect()),
        Err(_) => {
            let mut scratch = init();
            (0..n).map(|i| f(&mut scratch, i)).collect()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::map_indexed;

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
}
