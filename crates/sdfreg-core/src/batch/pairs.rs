//! Many pairs at once: every core busy, one pair per worker.
//!
//! One registration uses two threads well but leaves a larger machine idle, and a dataset is
//! aligned by the thousand. The pairs run on worker threads of their own, each pair on one worker (its
//! registration single-threaded), so the cores work on different pairs instead of sharing one.
//! Each result is bit-identical to registering that pair alone with the same settings and seed
//! (a result never depends on the thread count); a pair that fails gives its error in its place
//! and the others go on.
//!
//! - [`register_many`]: a slice of pairs in, a `Vec` of results in input order out.
//! - [`register_each`]: any iterator of keyed pairs, pulled lazily (a pair's clouds may be read
//!   only when a worker is free for it, so memory stays flat over thousands of pairs), each
//!   result handed to a callback as it finishes, with a flag that stops the batch early.
//! - [`register_each_loading`]: the same over items each worker makes into its pair (reading
//!   its files) on its own, so that the workers read at the same time.

use std::borrow::Cow;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use nalgebra::{Isometry3, Point3};

use crate::base::error::Error;
use crate::base::pool::in_pool_else_here;
use crate::model::mesh_model::MeshModel;
use crate::model::sdf_model::SdfModel;
use crate::pipeline::register::register;
use crate::pipeline::registration::Registration;
use crate::pipeline::settings::RegisterSettings;

/// What a pair's source is registered against.
#[derive(Clone, Debug)]
pub enum PairTarget<'a> {
    /// A target cloud, user units: Φ is fitted for this pair ([`crate::register()`]).
    Cloud(Cow<'a, [Point3<f64>]>),
    /// A stored model, Φ frozen ([`SdfModel::register`]); the same model may serve many pairs.
    Model(&'a SdfModel),
    /// A stored model the pair holds a share of: as [`PairTarget::Model`], for a model that a
    /// [`register_each_loading`] worker loads (or takes from a cache) as it reads the pair, and
    /// that is freed with the last pair holding it.
    SharedModel(Arc<SdfModel>),
    /// A mesh's exact distance field ([`MeshModel::register`]).
    Mesh(&'a MeshModel),
}

/// One pair of a batch. The clouds are borrowed or owned ([`Cow`]), so an iterator may read
/// them from files as it goes.
#[derive(Clone, Debug)]
pub struct Pair<'a> {
    /// The cloud to move, user units.
    pub source: Cow<'a, [Point3<f64>]>,
    /// What it is registered against.
    pub target: PairTarget<'a>,
    /// An initial guess mapping source into target (replaces the multi-start), or none.
    pub init: Option<Isometry3<f64>>,
    /// This pair's seed; none = the settings' [`RegisterSettings::seed`].
    pub seed: Option<u64>,
}

impl<'a> Pair<'a> {
    /// `source` against the cloud `target`, borrowed, no initial guess, the settings' seed.
    pub fn clouds(source: &'a [Point3<f64>], target: &'a [Point3<f64>]) -> Self {
        Pair {
            source: Cow::Borrowed(source),
            target: PairTarget::Cloud(Cow::Borrowed(target)),
            init: None,
            seed: None,
        }
    }

    /// `source` against the stored `model` (Φ frozen), no initial guess, the settings' seed.
    pub fn against_model(source: &'a [Point3<f64>], model: &'a SdfModel) -> Self {
        Pair {
            source: Cow::Borrowed(source),
            target: PairTarget::Model(model),
            init: None,
            seed: None,
        }
    }

    /// The same pair borrowing this one's clouds (no copy).
    pub fn borrowed(&self) -> Pair<'_> {
        Pair {
            source: Cow::Borrowed(&self.source),
            target: match &self.target {
                PairTarget::Cloud(points) => PairTarget::Cloud(Cow::Borrowed(points)),
                PairTarget::Model(model) => PairTarget::Model(model),
                PairTarget::SharedModel(model) => PairTarget::Model(model),
                PairTarget::Mesh(mesh) => PairTarget::Mesh(mesh),
            },
            init: self.init,
            seed: self.seed,
        }
    }

    /// Registers this pair alone with `settings` (its seed replacing theirs when it has one):
    /// what each pair of a batch gives.
    pub fn register(&self, settings: &RegisterSettings) -> Result<Registration, Error> {
        let seeded;
        let s = match self.seed {
            Some(seed) => {
                seeded = RegisterSettings {
                    seed,
                    ..settings.clone()
                };
                &seeded
            }
            None => settings,
        };
        match &self.target {
            PairTarget::Cloud(target) => register(&self.source, target, self.init.as_ref(), s),
            PairTarget::Model(model) => model.register(&self.source, self.init.as_ref(), s),
            PairTarget::SharedModel(model) => model.register(&self.source, self.init.as_ref(), s),
            PairTarget::Mesh(mesh) => mesh.register(&self.source, self.init.as_ref(), s),
        }
    }
}

/// Registers every pair with `settings` on `threads` workers (0 = one per core), one pair per
/// worker; results in input order, each equal to `pair.register(settings)` (see the module
/// docs). `settings.threads` is not read. Fails as a whole only for invalid settings.
pub fn register_many(
    pairs: &[Pair<'_>],
    settings: &RegisterSettings,
    threads: usize,
) -> Result<Vec<Result<Registration, Error>>, Error> {
    let slots: Mutex<Vec<Option<Result<Registration, Error>>>> =
        Mutex::new((0..pairs.len()).map(|_| None).collect());
    let never = AtomicBool::new(false);
    register_each(
        pairs.iter().map(Pair::borrowed).enumerate(),
        settings,
        threads,
        &never,
        |i, r| slots.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(r),
    )?;
    let slots = slots.into_inner().unwrap_or_else(|e| e.into_inner());
    Ok(slots
        .into_iter()
        .map(|r| r.expect("register_each hands every pair's result back when not stopped"))
        .collect())
}

/// Registers the keyed pairs `pairs` yields with `settings` on `threads` workers (0 = one per
/// core), one pair per worker, and calls `done(key, result)` as each finishes (in the order
/// they finish, from the worker threads). The iterator is pulled only when a worker is free
/// (by one worker at a time), so it may read each pair's clouds as it is asked for them; those
/// reads then run one at a time, where [`register_each_loading`] reads on every worker at once.
///
/// Once `stop` is set, no further pair is started; the pairs already running finish and are
/// reported, then the call returns. Each result equals `pair.register(settings)`;
/// `settings.threads` is not read. Fails as a whole only for invalid settings (before any pair
/// runs).
pub fn register_each<'a, K, I, D>(
    pairs: I,
    settings: &RegisterSettings,
    threads: usize,
    stop: &AtomicBool,
    done: D,
) -> Result<(), Error>
where
    K: Send,
    I: IntoIterator<Item = (K, Pair<'a>)>,
    I::IntoIter: Send,
    D: Fn(K, Result<Registration, Error>) + Sync,
{
    register_each_loading(pairs, Some, settings, threads, stop, done)
}

/// [`register_each`] over `items` that `load` makes into keyed pairs (reads their files, say) on
/// the worker that takes them, outside the lock that hands the items out: the workers read
/// their pairs at the same time. Items are still pulled one at a time, when a worker is free.
/// An item `load` gives no pair for (`None`: it could not be read, and `load` has said so) is
/// skipped; `done` is called for every pair made. Each result equals `pair.register(settings)`;
/// `settings.threads` is not read. Fails as a whole only for invalid settings (before any item
/// is loaded).
pub fn register_each_loading<'a, T, K, I, L, D>(
    items: I,
    load: L,
    settings: &RegisterSettings,
    threads: usize,
    stop: &AtomicBool,
    done: D,
) -> Result<(), Error>
where
    T: Send,
    K: Send,
    I: IntoIterator<Item = T>,
    I::IntoIter: Send,
    L: Fn(T) -> Option<(K, Pair<'a>)> + Sync,
    D: Fn(K, Result<Registration, Error>) + Sync,
{
    settings.validate()?;
    let one = RegisterSettings {
        threads: 1,
        ..settings.clone()
    };
    let workers = match threads {
        0 => std::thread::available_parallelism().map_or(1, |n| n.get()),
        n => n,
    };
    // Plain threads, each taking the next item when it is free. (Not a rayon pool: a pair's
    // registration runs in a pool of its own, and a rayon worker waiting on another pool steals
    // further pairs meanwhile, so more pairs would run at once than there are workers.)
    let items = Mutex::new(items.into_iter());
    let next = || {
        if stop.load(Ordering::Relaxed) {
            return None;
        }
        items.lock().unwrap_or_else(|e| e.into_inner()).next()
    };
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| {
                // The next item is taken and loaded (a caller's iterator or `load` may read
                // files) in the worker's one-thread pool, the one its registration runs in: a
                // reader that runs rayon tasks (LAZ decoding) then stays on this worker's
                // thread instead of making a pool of every core for each worker.
                while let Some(loaded) = in_pool_else_here(1, || next().map(&load)) {
                    if let Some((key, pair)) = loaded {
                        done(key, pair.register(&one));
                    }
                }
            });
        }
    });
    Ok(())
}
