//! The worker pool every parallel stage runs in: a local rayon pool, never the global one.

use crate::base::error::Error;

/// Runs `f` in a pool of `threads` workers (0 = one per core), never rayon's global one.
pub(crate) fn in_pool<R: Send>(threads: usize, f: impl FnOnce() -> R + Send) -> Result<R, Error> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::ThreadPool(e.to_string()))?;
    Ok(pool.install(f))
}
