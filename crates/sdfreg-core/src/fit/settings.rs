//! Settings of the SDF fit.

use crate::field::local_grid::LocalSettings;

/// Settings of the SDF fit. Lengths are in normalised units (target's largest side = 1).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitSettings {
    /// Adam steps before registration starts. Default 250 (was 500: with the batches below,
    /// see [`Self::batch_queries`]). From the learned initialisation
    /// ([`crate::MlpSettings::learned_init`], the `learned` preset) 150 fit better: on
    /// ModelNet's 36 shapes, each turned at random (`cargo run --release -p sdfreg-core
    /// --example learn_init -- --compare --shapes ../shared/data/modelnet40-half1`), mean |Φ|
    /// on the target's points 0.0055 after 150 steps from it, 0.0078 after 250 from the
    /// sphere; mean error of |Φ| about them 0.0125 against 0.0128.
    pub prefit_steps: usize,
    /// Adam steps of a stored model's pre-fit ([`crate::SdfModel::fit`]; a global Φ), in place
    /// of [`Self::prefit_steps`]: a model is fitted once and registered against many times,
    /// with Φ frozen and never refined, so it takes a longer fit. Default 2000: the work of the
    /// former pre-fit (500 steps of four times the batches), and its accuracy: tracking the
    /// 200 frames of `benches/track.py`, mean error 0.1466° (1000 steps: 0.157°;
    /// the former model 0.1465°). On the procedural room loop of five scans (`align`, whose
    /// pairs run through stored models), with 250 steps the worst pose ended 0.23° / 60 mm off,
    /// with 1000 0.23° / 7 mm. Model files written before this setting read 500, the pre-fit
    /// they had.
    #[serde(default = "five_hundred")]
    pub model_prefit_steps: usize,
    /// Adam learning rate of the pre-fit. Default 2e-3.
    pub prefit_lr: f32,
    /// Adam steps in each coarse-to-fine alternation. Default 10 (was 40: the stored model's
    /// registration, Φ never refined, is as accurate on the unseen shapes; the alternations'
    /// worth is in choosing among the hypotheses). A local Φ (a scene) takes
    /// [`LocalSettings::refine_steps`] instead.
    pub refine_steps: usize,
    /// Adam learning rate of the alternations. Default 1e-3.
    pub refine_lr: f32,
    /// Perturbation queries per Adam step. Default 256 (was 1024; the batches below were
    /// 512). Measured on `sdfreg eval --shapes ../shared/data/modelnet40-half1 --protocol all`
    /// (20 pairs a protocol): a quarter of every batch alone, 0.39 times the time, the same
    /// errors on every shape but the surfaces of revolution (bottles, bowls, cups, the cone,
    /// whose rotation about the axis the data do not fix); with 250 pre-fit steps and 10
    /// refinement steps, 0.21 times. A scene's network took these batches already
    /// ([`LocalSettings::network_batch_divisor`] 4 of the former ones).
    pub batch_queries: usize,
    /// Perturbation queries per Adam step once moved-source queries exist (the coarse-to-fine
    /// phase, whose focus is the source's neighbourhood). Default 128.
    pub refine_batch_queries: usize,
    /// Accumulated moved-source queries per Adam step (once any exist). Default 128.
    pub batch_source: usize,
    /// Target points per Adam step for the surface term. Default 128.
    pub batch_surface: usize,
    /// Size of the fixed pool of perturbation queries. Default 16384.
    pub query_pool: usize,
    /// σ of a query is the distance to this neighbour among `sigma_sample` target points.
    /// Default 50.
    pub sigma_neighbour: usize,
    /// Target points the σ neighbourhoods and the pool are drawn from (density independent).
    /// Default 1024.
    pub sigma_sample: usize,
    /// Weight λ_q of the surface term `|Φ(q)|`. Default 0.1.
    pub lambda_surface: f32,
    /// Weight λ_e of the Eikonal term. Default 0.001.
    pub lambda_eikonal: f32,
    /// At most this many moved-source queries are kept (oldest dropped first). Default 16384.
    pub max_source_queries: usize,
    /// The local part of Φ (scenes): when it is used and how fine it is. Settings written
    /// before it existed (model files of earlier versions) lack it and read as
    /// [`LocalSettings::legacy`]: the global MLP their Φ was.
    #[serde(default = "LocalSettings::legacy")]
    pub local: LocalSettings,
}

impl FitSettings {
    /// Checks every field; the error names it (`fit.refine_lr`, …).
    pub fn validate(&self) -> Result<(), crate::base::error::Error> {
        use crate::base::check;
        check::positive("fit.prefit_lr", self.prefit_lr as f64)?;
        check::positive("fit.refine_lr", self.refine_lr as f64)?;
        check::count_at_least("fit.batch_queries", self.batch_queries, 1)?;
        check::count_at_least("fit.refine_batch_queries", self.refine_batch_queries, 1)?;
        check::count_at_least("fit.query_pool", self.query_pool, 1)?;
        check::count_at_least("fit.sigma_neighbour", self.sigma_neighbour, 1)?;
        check::count_at_least("fit.sigma_sample", self.sigma_sample, 2)?;
        check::non_negative("fit.lambda_surface", self.lambda_surface as f64)?;
        check::non_negative("fit.lambda_eikonal", self.lambda_eikonal as f64)?;
        check::count_at_least("fit.max_source_queries", self.max_source_queries, 1)?;
        self.local.validate()
    }
}

/// [`FitSettings::model_prefit_steps`] of settings written before it existed.
fn five_hundred() -> usize {
    500
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            prefit_steps: 250,
            model_prefit_steps: 2000,
            prefit_lr: 2e-3,
            refine_steps: 10,
            refine_lr: 1e-3,
            batch_queries: 256,
            refine_batch_queries: 128,
            batch_source: 128,
            batch_surface: 128,
            query_pool: 16384,
            sigma_neighbour: 50,
            sigma_sample: 1024,
            lambda_surface: 0.1,
            lambda_eikonal: 0.001,
            max_source_queries: 16384,
            local: LocalSettings::default(),
        }
    }
}
