//! Many pairs at once: every core busy, one pair per worker.
//!
//! One registration uses two threads well but leaves a larger machine idle, and a dataset is
//! aligned by the thousand. [`register_many`] runs the pairs on a pool of its own, each pair on
//! one worker (its registration single-threaded), so the cores work on different pairs instead
//! of sharing one. Results come back in input order; each is bit-identical to registering that
//! pair alone with the same settings (the result never depends on the thread count); a pair
//! that fails gives its error in its place and the others go on.

use nalgebra::{Isometry3, Point3};
use rayon::prelude::*;

use crate::error::Error;
use crate::model::SdfModel;
use crate::{register, RegisterSettings, Registration};

/// What a pair's source is registered against.
#[derive(Clone, Copy, Debug)]
pub enum PairTarget<'a> {
    /// A target cloud: Φ is fitted for this pair ([`crate::register()`]).
    Cloud(&'a [Point3<f64>]),
    /// A stored model, Φ frozen ([`SdfModel::register`]); the same model may serve many pairs.
    Model(&'a SdfModel),
}

/// One pair of a batch.
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// The cloud to move, user units.
    pub source: &'a [Point3<f64>],
    /// What it is registered against.
    pub target: PairTarget<'a>,
    /// An initial guess mapping source into target (replaces the multi-start), or none.
    pub init: Option<Isometry3<f64>>,
}

/// Registers every pair with `settings` on `threads` workers (0 = one per core), one pair per
/// worker; results in input order, each equal to registering that pair alone (see the module
/// docs). `settings.threads` is not read.
pub fn register_many(
    pairs: &[Pair<'_>],
    settings: &RegisterSettings,
    threads: usize,
) -> Result<Vec<Result<Registration, Error>>, Error> {
    settings.validate()?;
    let one = RegisterSettings {
        threads: 1,
        ..settings.clone()
    };
    crate::register::in_pool(threads, || {
        pairs
            .par_iter()
            .with_max_len(1)
            .map(|p| match p.target {
                PairTarget::Cloud(target) => register(p.source, target, p.init.as_ref(), &one),
                PairTarget::Model(model) => model.register(p.source, p.init.as_ref(), &one),
            })
            .collect()
    })
}
