//! Settings of the SDF fit.

use crate::field::local_grid::LocalSettings;

/// Settings of the SDF fit. Lengths are in normalised units (target's largest side = 1).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitSettings {
    /// Adam steps before registration starts. Default 500.
    pub prefit_steps: usize,
    /// Adam learning rate of the pre-fit. Default 2e-3.
    pub prefit_lr: f32,
    /// Adam steps in each coarse-to-fine alternation. Default 40.
    pub refine_steps: usize,
    /// Adam learning rate of the alternations. Default 1e-3.
    pub refine_lr: f32,
    /// Perturbation queries per Adam step. Default 1024.
    pub batch_queries: usize,
    /// Perturbation queries per Adam step once moved-source queries exist (the coarse-to-fine
    /// phase, whose focus is the source's neighbourhood). Default 512.
    pub refine_batch_queries: usize,
    /// Accumulated moved-source queries per Adam step (once any exist). Default 512.
    pub batch_source: usize,
    /// Target points per Adam step for the surface term. Default 512.
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

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            prefit_steps: 500,
            prefit_lr: 2e-3,
            refine_steps: 40,
            refine_lr: 1e-3,
            batch_queries: 1024,
            refine_batch_queries: 512,
            batch_source: 512,
            batch_surface: 512,
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
