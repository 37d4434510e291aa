//! Stages 1–2 for the target: its unit frame and the pre-fit of Φ, shared by
//! [`crate::register()`] and [`crate::SdfModel::fit`].

use nalgebra::Point3;
use rand_chacha::ChaCha8Rng;

use crate::base::error::Error;
use crate::field::learned_init::shipped_for;
use crate::fit::fitter::SdfFitter;
use crate::geometry::cloud::{subsample, Normalization};
use crate::pipeline::report::Stage;
use crate::pipeline::settings::RegisterSettings;

/// Salt of the SDF fit's seed (its random stream differs from the registration's).
pub(crate) const FIT_SEED_SALT: u64 = 0x5DF;

/// Normalises `target` (user units and frame) into its unit frame, draws its subsample from
/// `rng` (the registration's stream) and pre-fits Φ, from the learned initialisation when
/// `RegisterSettings::starts_learned`, for `RegisterSettings::prefit_steps` Adam
/// steps (a local Φ's corrections are then set from planes), reporting [`Stage::Prefit`] to
/// `progress`; `stored` for a stored model's fit.
pub(crate) fn prefit(
    target: &[Point3<f64>],
    s: &RegisterSettings,
    stored: bool,
    rng: &mut ChaCha8Rng,
    progress: &(dyn Fn(Stage) + Sync),
) -> Result<(Normalization, SdfFitter), Error> {
    let norm = Normalization::from_target(target)?;
    let unit: Vec<[f32; 3]> = subsample(target, s.max_target_points, rng)
        .iter()
        .map(|p| norm.to_unit(p))
        .collect();
    let mut fit = s.fit.clone();
    fit.local = fit.local.for_extent(norm.scale);
    let mut fitter = SdfFitter::try_new(unit, &s.mlp, &fit, s.seed ^ FIT_SEED_SALT)?;
    let local = fitter.field().grid().is_some();
    if s.starts_learned(local, stored) {
        let m = &s.mlp;
        if let Some(init) = shipped_for(m.width, m.depth, m.beta) {
            fitter.restart_from(init);
        }
    }
    let total = s.prefit_steps(local, stored);
    let chunk = 50.max(total / 10);
    let mut done = 0;
    while done < total {
        let n = chunk.min(total - done);
        fitter.train(n, s.fit.prefit_lr);
        done += n;
        progress(Stage::Prefit(done, total));
    }
    if s.fit.local.plane_fit {
        fitter.start_local_from_planes();
    }
    Ok((norm, fitter))
}
