//! The worker pool every parallel stage runs in: a local rayon pool, never the global one.
//!
//! Each calling thread keeps its pools (one per thread count asked for) for its next calls: a
//! pool of two threads takes about 2.5 ms to start and warm up, as much as a whole tracked
//! frame, and a robot calls once per frame. Per calling thread, so that the plain worker
//! threads of a batch ([`crate::register_many`]), each asking for one thread, still run side
//! by side; the pools end with their thread. A forked child (Python's `multiprocessing` on
//! Linux) inherits the pools but not their threads: it leaves them alone and starts its own.

use std::cell::RefCell;
use std::sync::{Arc, OnceLock};

use rayon::ThreadPool;

use crate::base::error::Error;

/// A thread's pools, by the thread count they were asked for, and the process that made them.
#[derive(Default)]
struct Pools {
    process: u32,
    pools: Vec<(usize, Arc<ThreadPool>)>,
}

thread_local! {
    /// This thread's pools.
    static POOLS: RefCell<Pools> = RefCell::new(Pools::default());
}

/// The value in `cell`, made by `make` when the cell is empty: for a cell shared by
/// registrations (a stored model's) whose maker runs rayon tasks.
///
/// Not `OnceLock::get_or_init`: a worker waiting on the maker's tasks may take up another task
/// that asks for the same cell (registrations through one model run from a caller's own
/// parallel loop), and `get_or_init` would wait there forever on its own maker. Such a reader
/// makes a value of its own instead and the first one stored is kept, so `make` must give the
/// same value wherever it runs.
pub(crate) fn get_or_make<T>(cell: &OnceLock<T>, make: impl FnOnce() -> T) -> &T {
    if let Some(value) = cell.get() {
        return value;
    }
    let value = make();
    cell.get_or_init(|| value)
}

/// Runs `f` in a pool of `threads` workers (0 = one per core), never rayon's global one: the
/// calling thread's pool of that size, made on its first call.
pub(crate) fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> Result<R, Error> {
    let pool = pool(threads)?;
    Ok(pool.install(f))
}

/// [`in_pool`], or `f` on the calling thread when that pool cannot be made (the system refuses
/// threads): for work that does not need the pool, only prefers it.
pub(crate) fn in_pool_else_here<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> R {
    match pool(threads) {
        Ok(pool) => pool.install(f),
        Err(_) => f(),
    }
}

/// Runs `f(true)` where the rayon tasks it starts stay off rayon's global pool: in the pool the
/// caller is already in (whose size the caller chose), else in the calling thread's pool of one
/// worker per core. When that pool cannot be made (the system refuses threads), `f(false)` on
/// the calling thread, for `f` to do its work without rayon.
pub(crate) fn in_a_pool<R: Send>(f: impl FnOnce(bool) -> R + Send) -> R {
    if rayon::current_thread_index().is_some() {
        return f(true);
    }
    match pool(0) {
        Ok(pool) => pool.install(|| f(true)),
        Err(_) => f(false),
    }
}

/// The calling thread's pool of `threads` workers, made when first asked for.
fn pool(threads: usize) -> Result<Arc<ThreadPool>, Error> {
    let process = std::process::id();
    let kept = POOLS.with_borrow_mut(|kept| {
        if kept.process != process {
            // Made by the parent of a fork: their threads are not in this process, and
            // dropping them would wait on those threads. Left alone.
            std::mem::forget(std::mem::take(&mut kept.pools));
            kept.process = process;
        }
        kept.pools
            .iter()
            .find(|(n, _)| *n == threads)
            .map(|(_, p)| p.clone())
    });
    if let Some(pool) = kept {
        return Ok(pool);
    }
    let pool = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .map_err(|e| Error::ThreadPool(e.to_string()))?,
    );
    POOLS.with_borrow_mut(|kept| kept.pools.push((threads, pool.clone())));
    Ok(pool)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_thread_keeps_one_pool_per_size_and_other_threads_get_their_own() {
        let workers = |n| in_pool(n, rayon::current_num_threads).unwrap();
        assert_eq!((workers(1), workers(3)), (1, 3));
        let here = pool(3).unwrap();
        assert!(Arc::ptr_eq(&here, &pool(3).unwrap()));
        let there = std::thread::spawn(|| pool(3).unwrap()).join().unwrap();
        assert!(!Arc::ptr_eq(&here, &there));
    }

    #[test]
    fn work_asked_for_in_a_pool_stays_in_the_callers_or_gets_the_threads_own() {
        // From a plain thread: that thread's pool of one worker per core.
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let plain = std::thread::spawn(|| {
            let own = pool(0).unwrap();
            in_a_pool(|parallel| {
                let index = rayon::current_thread_index();
                (
                    parallel,
                    index.is_some(),
                    rayon::current_num_threads(),
                    own.current_thread_index() == index,
                )
            })
        })
        .join()
        .unwrap();
        assert_eq!(plain, (true, true, cores, true));
        // From inside a pool: that pool, whatever its size.
        let inside = in_pool(1, || in_a_pool(|_| rayon::current_num_threads())).unwrap();
        assert_eq!(inside, 1);
    }
}
