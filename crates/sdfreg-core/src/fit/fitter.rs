//! Fitting the neural SDF Φ to the target cloud, self-supervised (no normals needed).
//!
//! Losses per Adam step (paper eq. 18, 18-1, 19, 20), all in the unit frame:
//! - projection: a query `x` whose nearest target point is `t` is pulled there along the SDF,
//!   `‖x − Φ(x) ∇Φ(x)/‖∇Φ(x)‖ − t‖²`, averaged separately over the perturbation queries and
//!   over the accumulated moved-source queries (coarse-to-fine, eq. 18-1);
//! - surface: `λ_q |Φ(q)|` on target points;
//! - Eikonal: `λ_e (‖∇Φ(x)‖ − 1)²` on all queries.
//!
//! Perturbation queries are target points moved by `N(0, σ²)`, with σ per point the distance
//! to its k-th neighbour (Neural-Pull); nearest target points come from a k-d tree (kiddo).
//!
//! A local Φ's corrections (scenes) are not trained by default: the network trains alone, then
//! [`SdfFitter::start_local_from_planes`] sets them in closed form and later steps keep them
//! following the network.
//!
//! Entry point: [`SdfFitter`].

use std::num::NonZeroUsize;
use std::sync::OnceLock;

use kiddo::SquaredEuclidean;
use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;

use crate::base::error::Error;
use crate::field::local_grid::LocalGrid;
use crate::field::mlp::{Mlp, MlpSettings, Workspace};
use crate::field::sdf::SdfField;
use crate::fit::adam::Adam;
use crate::fit::settings::FitSettings;
use crate::geometry::tree::{build_tree, target_spacing, Tree};

/// Queries (and surface points) per task of an Adam step. The step's batches are a few hundred
/// (256 perturbation queries and 128 surface points in the pre-fit), so blocks of the field's
/// [`crate::field::BLOCK`] (256) made two unequal tasks for two cores; blocks of 64 make six,
/// and the pre-fit of a 1024-point object takes 0.78 times as long (the coarse-to-fine loop
/// 0.7). Fixed, so that a step's sum, taken in block order, does not depend on the threads.
const FIT_BLOCK: usize = 64;

/// One query of the projection loss: the point, its nearest target point and its weight.
#[derive(Clone, Copy, Debug)]
struct Query {
    x: [f32; 3],
    t: [f32; 3],
    w: f32,
}

/// The part of an [`SdfFitter`] that fitting changes (see [`SdfFitter::state`]).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct FitterState {
    /// Φ's parameters.
    pub params: Vec<f32>,
    /// Adam's first moments.
    pub adam_m: Vec<f32>,
    /// Adam's second moments.
    pub adam_v: Vec<f32>,
    /// Adam steps taken.
    pub adam_steps: i32,
    /// Position in the fit's random stream.
    pub rng_word_pos: u128,
}

/// Loss terms of the last Adam step, for monitoring.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FitLoss {
    /// Mean projection loss over the perturbation queries (normalised units²).
    pub projection: f64,
    /// Total weighted loss.
    pub total: f64,
}

/// How near Φ is to the target's distance (normalised units), [`SdfFitter::quality`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FitQuality {
    /// Mean |Φ| on the target's points (0 for a Φ whose zero level set holds them all).
    pub on_target: f64,
    /// Mean of `| |Φ(x)| − d(x) |` over probes `x` near the target, `d` the distance to the
    /// nearest target point: half of them spread by 0.02 about target points, half by 0.1.
    pub near_target: f64,
}

/// The neural SDF of a target cloud and the state needed to keep fitting it.
#[derive(Clone, Debug)]
pub struct SdfFitter {
    field: SdfField,
    adam: Adam,
    /// Adam's moments of the local corrections (empty without them).
    adam_local: Adam,
    settings: FitSettings,
    target: Vec<[f32; 3]>,
    tree: Tree,
    /// The fixed query pools: drawn when the fit is set up ([`Self::new`]), or, for a fitter
    /// restored from a file ([`Self::for_restore`]), when a step first needs them.
    pools: OnceLock<QueryPools>,
    /// The random stream's seed and its position after the network's initial draws, where the
    /// pools' draws begin.
    pools_from: (u64, u128),
    source_queries: Vec<([f32; 3], [f32; 3])>,
    /// With corrections from planes: each corner's signed distance to its plane, by slot (NaN
    /// without one); empty otherwise (a global model, trained corrections, or before
    /// [`Self::start_local_from_planes`]).
    plane_distance: Vec<f32>,
    /// A restored local model's `plane_distance`, not computed yet ([`Self::for_restore`]).
    planes_pending: bool,
    rng: ChaCha8Rng,
    /// Per-block workspace, gradient and local gradient (slot, value), kept between steps (no
    /// allocation in the loop).
    scratch: Vec<BlockScratch>,
    /// The target's median point spacing ([`target_spacing`]), unit frame.
    spacing: f64,
}

/// A fit's fixed pools of queries, each with its nearest target point.
#[derive(Clone, Debug)]
struct QueryPools {
    /// Target points moved by `N(0, σ²)` (the perturbation queries).
    pool: Vec<([f32; 3], [f32; 3])>,
    /// The local part's queries about the target's points (empty for a global model, or
    /// corrections from planes).
    local_pool: Vec<([f32; 3], [f32; 3])>,
}

impl QueryPools {
    /// The pools of a fit on `target` (its k-d `tree`, its local grid `local`), drawn from
    /// `rng` in a fixed order: the σ centres, the perturbation queries, the local queries.
    fn draw(
        rng: &mut ChaCha8Rng,
        target: &[[f32; 3]],
        tree: &Tree,
        local: Option<&LocalGrid>,
        settings: &FitSettings,
    ) -> Self {
        let m = target.len();
        let s = settings.sigma_sample.clamp(2, m.max(2)).min(m);
        let centres: Vec<[f32; 3]> = if s >= m {
            target.to_vec()
        } else {
            sample(rng, m, s).into_iter().map(|i| target[i]).collect()
        };
        let centre_tree = build_tree(&centres);
        let k = settings.sigma_neighbour.clamp(1, centres.len() - 1);
        let sigmas: Vec<f32> = centres
            .par_iter()
            .map(|c| {
                let nn =
                    centre_tree.nearest_n::<SquaredEuclidean>(c, NonZeroUsize::new(k + 1).unwrap());
                nn.last()
                    .map(|n| n.distance.sqrt())
                    .unwrap_or(0.0)
                    .max(1e-4)
            })
            .collect();
        let queries: Vec<[f32; 3]> = (0..settings.query_pool)
            .map(|i| {
                let j = i % centres.len();
                let c = centres[j];
                let mut q = [0.0f32; 3];
                for a in 0..3 {
                    let n: f32 = StandardNormal.sample(rng);
                    q[a] = c[a] + sigmas[j] * n;
                }
                q
            })
            .collect();
        let nearest = |x: &[f32; 3]| target[tree.nearest_one::<SquaredEuclidean>(x).item as usize];
        let pool = queries.par_iter().map(|q| (*q, nearest(q))).collect();
        let local_pool = match local {
            Some(grid) if !settings.local.plane_fit => {
                // Target points moved by a fraction of a voxel (the pool's σ is the scale of the
                // whole target), each with its nearest target point.
                let sigma = (settings.local.sigma_voxels * grid.voxel() as f64) as f32;
                let moved: Vec<[f32; 3]> = (0..settings.local.pool)
                    .map(|_| {
                        let c = target[rng.random_range(0..target.len())];
                        [0, 1, 2].map(|a| {
                            let n: f32 = StandardNormal.sample(rng);
                            c[a] + sigma * n
                        })
                    })
                    .collect();
                moved.par_iter().map(|x| (*x, nearest(x))).collect()
            }
            _ => Vec::new(),
        };
        Self { pool, local_pool }
    }
}

/// One block's workspace, network gradient and local gradient `(slot, ∂L/∂θ)`.
type BlockScratch = (Workspace, Vec<f32>, Vec<(u32, f32)>);

/// Loss of one query and its derivatives: `w ‖x − Φ n − t‖² + w_e (‖g‖ − 1)²` with
/// `g = ∇Φ(x)`, `n = g/‖g‖`. Returns `(projection term ‖·‖², total, ∂/∂Φ, ∂/∂g)`.
fn query_loss(
    x: &[f32; 3],
    t: &[f32; 3],
    w: f32,
    we: f32,
    phi: f32,
    g: &[f32; 3],
) -> (f32, f32, f32, [f32; 3]) {
    let gn = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt().max(1e-8);
    let n = [g[0] / gn, g[1] / gn, g[2] / gn];
    let d = [
        x[0] - phi * n[0] - t[0],
        x[1] - phi * n[1] - t[1],
        x[2] - phi * n[2] - t[2],
    ];
    let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
    let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    let e = gn - 1.0;
    // ∂/∂Φ ‖d‖² = −2 d·n; ∂/∂g ‖d‖² = −2Φ/‖g‖ (I − n nᵀ) d; ∂/∂g (‖g‖ − 1)² = 2 e n.
    let a = -2.0 * w * phi / gn;
    let dg = [0, 1, 2].map(|k| a * (d[k] - dn * n[k]) + 2.0 * we * e * n[k]);
    (d2, w * d2 + we * e * e, -2.0 * w * dn, dg)
}

/// What one Adam step reads: the queries with their weights, the surface points, and the
/// loss weights.
struct Batch {
    queries: Vec<Query>,
    surface: Vec<[f32; 3]>,
    /// The perturbation queries fill the first `nq` places of `queries`.
    nq: usize,
    /// Weight of a perturbation query's projection loss.
    wq: f32,
    /// Weight of each query's Eikonal term.
    we: f32,
    /// Weight of each surface point's |Φ|.
    wsurf: f32,
}

impl SdfFitter {
    /// Sets up the fit on `target` (unit frame): initial network, k-d tree, query pool, and
    /// the local grid when the settings ask for one, whatever its size ([`Self::try_new`]
    /// refuses a grid the settings bound). `target` must hold at least 2 points.
    pub fn new(
        target: Vec<[f32; 3]>,
        mlp: &MlpSettings,
        settings: &FitSettings,
        seed: u64,
    ) -> Self {
        Self::unpooled(target, mlp, settings, seed).with_pools()
    }

    /// [`Self::new`] but for the query pools, for a fitter whose state is then restored
    /// ([`Self::restore`]): a model read from a file, which most often only registers. The pools
    /// are drawn when a step first needs them, the same as [`Self::new`]'s (from the seed's
    /// stream at the same position). Drawing them is a nearest-point search for each of their
    /// 16,384 queries (65,536 more for corrections trained by Adam), most of them far from
    /// the points: 90 ms of the 170 ms that reading a room scan's model took.
    ///
    /// A local model fitted with corrections from planes holds the network its planes were
    /// set against ([`Self::start_local_from_planes`] ends the fit), so its corners' plane
    /// distances, which the file does not hold, are computed again, the same, before a step
    /// first changes the network; without them its corrections would no longer follow the
    /// network while it is refined.
    pub(crate) fn for_restore(
        target: Vec<[f32; 3]>,
        mlp: &MlpSettings,
        settings: &FitSettings,
        seed: u64,
    ) -> Self {
        let mut fitter = Self::unpooled(target, mlp, settings, seed);
        fitter.planes_pending = fitter.settings.local.plane_fit && fitter.field.grid().is_some();
        fitter
    }

    /// [`Self::new`] without its query pools.
    fn unpooled(
        target: Vec<[f32; 3]>,
        mlp: &MlpSettings,
        settings: &FitSettings,
        seed: u64,
    ) -> Self {
        let tree = build_tree(&target);
        let spacing = target_spacing(&target, &tree);
        let local = settings
            .local
            .voxel(spacing)
            .map(|voxel| LocalGrid::allocate(&target, voxel, settings.local.band));
        Self::assemble(target, tree, spacing, local, mlp, settings, seed)
    }

    /// [`Self::new`], refusing a local grid whose voxel is below
    /// [`LocalSettings::min_voxel_spacings`](crate::field::local_grid::LocalSettings) target
    /// spacings or whose size is above its `max_memory_mib`, before it is built
    /// ([`LocalSettings::grid`](crate::field::local_grid::LocalSettings::grid)).
    pub fn try_new(
        target: Vec<[f32; 3]>,
        mlp: &MlpSettings,
        settings: &FitSettings,
        seed: u64,
    ) -> Result<Self, Error> {
        let tree = build_tree(&target);
        let spacing = target_spacing(&target, &tree);
        let local = settings.local.grid(&target, spacing)?;
        Ok(Self::assemble(target, tree, spacing, local, mlp, settings, seed).with_pools())
    }

    /// Draws the query pools now, and moves the fit's random stream past them (from where
    /// [`Self::assemble`] left it: just past the network's initial draws).
    fn with_pools(mut self) -> Self {
        let (pools, after) = self.draw_pools();
        self.rng.set_word_pos(after);
        self.pools = OnceLock::from(pools);
        self
    }

    /// The query pools, drawn from the fit's random stream at `pools_from`,
    /// and the stream's position after them.
    fn draw_pools(&self) -> (QueryPools, u128) {
        let (seed, word_pos) = self.pools_from;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_word_pos(word_pos);
        let pools = QueryPools::draw(
            &mut rng,
            &self.target,
            &self.tree,
            self.field.grid(),
            &self.settings,
        );
        (pools, rng.get_word_pos())
    }

    /// The fit on `target` with its k-d `tree`, median `spacing` and local grid, its query
    /// pools not drawn yet ([`Self::with_pools`]).
    fn assemble(
        target: Vec<[f32; 3]>,
        tree: Tree,
        spacing: f64,
        local: Option<LocalGrid>,
        mlp: &MlpSettings,
        settings: &FitSettings,
        seed: u64,
    ) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let net = Mlp::new(mlp, &mut rng);
        let pools_from = (seed, rng.get_word_pos());
        let n_local = local.as_ref().map_or(0, LocalGrid::len);
        Self {
            adam: Adam::new(net.num_params()),
            adam_local: Adam::new(n_local),
            field: SdfField::new(net, local),
            settings: settings.clone(),
            target,
            tree,
            pools: OnceLock::new(),
            pools_from,
            source_queries: Vec::new(),
            plane_distance: Vec::new(),
            planes_pending: false,
            rng,
            scratch: Vec::new(),
            spacing,
        }
    }

    /// How near Φ is to the target's distance ([`FitQuality`]), from at most `probes` target
    /// points and `probes` probes about them, drawn by `seed` (not the fit's random stream).
    /// The network alone: a local model's corrections are not read.
    pub fn quality(&self, probes: usize, seed: u64) -> FitQuality {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let t = &self.target;
        let on: Vec<[f32; 3]> = (0..probes.min(t.len()))
            .map(|_| t[rng.random_range(0..t.len())])
            .collect();
        let near: Vec<[f32; 3]> = (0..probes)
            .map(|i| {
                let c = t[rng.random_range(0..t.len())];
                let spread = if i % 2 == 0 { 0.02 } else { 0.1 };
                c.map(|v| {
                    let n: f32 = StandardNormal.sample(&mut rng);
                    v + spread * n
                })
            })
            .collect();
        let mlp = self.field.mlp();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (phi_on, _) = mlp.eval(&on, false);
        let (phi_near, _) = mlp.eval(&near, false);
        let errors: Vec<f64> = near
            .iter()
            .zip(&phi_near)
            .map(|(x, phi)| {
                let d = self.tree.nearest_one::<SquaredEuclidean>(x).distance.sqrt();
                (phi.abs() - d).abs() as f64
            })
            .collect();
        FitQuality {
            on_target: mean(&phi_on.iter().map(|v| v.abs() as f64).collect::<Vec<_>>()),
            near_target: mean(&errors),
        }
    }

    /// Replaces the network's parameters by `params` (laid out as [`Mlp::params`]) and resets
    /// the optimiser: the fit goes on from them as from a fresh start. `None` (nothing changed)
    /// when their count is not the network's.
    pub fn restart_from(&mut self, params: &[f32]) -> Option<()> {
        let net = self.field.mlp_mut().params_mut();
        if params.len() != net.len() {
            return None;
        }
        net.copy_from_slice(params);
        self.adam = Adam::new(params.len());
        Some(())
    }

    /// The target points' median spacing (distance to the nearest other target point, unit
    /// frame; [`target_spacing`]), computed once with the tree.
    pub(crate) fn spacing(&self) -> f64 {
        self.spacing
    }

    /// The current network (Φ's global part).
    pub fn mlp(&self) -> &Mlp {
        self.field.mlp()
    }

    /// Φ: the network and, for a local model, its grid of corrections.
    pub fn field(&self) -> &SdfField {
        &self.field
    }

    /// The target points (unit frame).
    pub fn target(&self) -> &[[f32; 3]] {
        &self.target
    }

    /// The k-d tree over the target points.
    pub fn tree(&self) -> &Tree {
        &self.tree
    }

    /// The fit's settings.
    pub fn settings(&self) -> &FitSettings {
        &self.settings
    }

    /// What a fitter holds beyond what [`SdfFitter::new`] rebuilds from the target, the
    /// settings and the seed: Φ's parameters, the optimiser's moments and step count, and the
    /// position in the random stream. Moved-source queries are not part of it.
    pub(crate) fn state(&self) -> FitterState {
        let cat = |a: &[f32], b: &[f32]| [a, b].concat();
        FitterState {
            params: cat(self.field.mlp().params(), self.field.theta()),
            adam_m: cat(&self.adam.m, &self.adam_local.m),
            adam_v: cat(&self.adam.v, &self.adam_local.v),
            adam_steps: self.adam.t,
            rng_word_pos: self.rng.get_word_pos(),
        }
    }

    /// Parameters of Φ: the network's, then the local corrections' (none for a global model).
    pub fn num_params(&self) -> usize {
        self.field.mlp().num_params() + self.field.theta().len()
    }

    /// Restores a [`FitterState`] taken from a fitter built with the same target, settings and
    /// seed; `None` when its vectors do not fit this Φ ([`Self::num_params`]).
    pub(crate) fn restore(&mut self, state: FitterState) -> Option<()> {
        let n = self.num_params();
        if state.params.len() != n || state.adam_m.len() != n || state.adam_v.len() != n {
            return None;
        }
        let k = self.field.mlp().num_params();
        self.field
            .mlp_mut()
            .params_mut()
            .copy_from_slice(&state.params[..k]);
        self.field.theta_mut().copy_from_slice(&state.params[k..]);
        self.adam = Adam {
            m: state.adam_m[..k].to_vec(),
            v: state.adam_v[..k].to_vec(),
            t: state.adam_steps,
        };
        self.adam_local = Adam {
            m: state.adam_m[k..].to_vec(),
            v: state.adam_v[k..].to_vec(),
            t: state.adam_steps,
        };
        self.rng.set_word_pos(state.rng_word_pos);
        self.source_queries.clear();
        Some(())
    }

    /// Sets the local corrections in closed form ([`LocalSettings::plane_fit`]): Φ at each
    /// corner becomes its signed distance to the plane of the target points about it
    /// ([`LocalGrid::corner_planes`]), the normals turned to agree with each other and, as a
    /// whole, with the network's gradient ([`LocalGrid::orient_planes`]), so that Φ keeps the
    /// network's sign where the corrections fade out. Corners without a plane get no
    /// correction. Later Adam steps train the network alone and the corrections follow it
    /// ([`Self::train`]). Nothing for a global model. Returns the corners given a plane.
    ///
    /// [`LocalSettings::plane_fit`]: crate::field::local_grid::LocalSettings::plane_fit
    pub fn start_local_from_planes(&mut self) -> usize {
        let Some(values) = self.set_plane_distance() else {
            return 0;
        };
        self.set_corrections(&values);
        self.plane_distance.iter().filter(|d| !d.is_nan()).count()
    }

    /// Sets `plane_distance` from the corners' planes, turned by the network as it is now;
    /// returns the network's values at the corners (`None` for a global model).
    fn set_plane_distance(&mut self) -> Option<Vec<f32>> {
        let grid = self.field.grid()?;
        let mut planes = grid.corner_planes(&self.target);
        let corners = grid.corner_positions();
        let (values, gradients) = self.field.mlp().eval(&corners, true);
        grid.orient_planes(&mut planes, &gradients);
        self.plane_distance = planes
            .iter()
            .zip(&corners)
            .map(|(plane, c)| {
                plane.map_or(f32::NAN, |(mean, n)| {
                    (0..3).map(|a| n[a] * (c[a] as f64 - mean[a])).sum::<f64>() as f32
                })
            })
            .collect();
        self.planes_pending = false;
        Some(values)
    }

    /// Sets each correction so that Φ at its corner is its plane distance (none without a
    /// plane), for the network as it is now.
    fn follow_planes(&mut self) {
        let Some(grid) = self.field.grid() else {
            return;
        };
        let (values, _) = self.field.mlp().eval(&grid.corner_positions(), false);
        self.set_corrections(&values);
    }

    /// Sets each correction so that Φ at its corner is its plane distance, given the network's
    /// `values` at the corners (by slot).
    fn set_corrections(&mut self, values: &[f32]) {
        let Some(h) = self.field.grid().map(LocalGrid::voxel) else {
            return;
        };
        for ((t, d), v) in self
            .field
            .theta_mut()
            .iter_mut()
            .zip(&self.plane_distance)
            .zip(values)
        {
            *t = if d.is_nan() { 0.0 } else { (d - v) / h };
        }
    }

    /// Adds moved source points as queries of the coarse-to-fine loss (eq. 18-1).
    pub fn add_source_queries(&mut self, points: &[[f32; 3]]) {
        let new: Vec<([f32; 3], [f32; 3])> = points
            .par_iter()
            .map(|q| {
                (
                    *q,
                    self.target[self.tree.nearest_one::<SquaredEuclidean>(q).item as usize],
                )
            })
            .collect();
        self.source_queries.extend(new);
        let max = self.settings.max_source_queries.max(1);
        if self.source_queries.len() > max {
            let drop = self.source_queries.len() - max;
            self.source_queries.drain(..drop);
        }
    }

    /// Runs `steps` Adam steps at learning rate `lr`; returns the loss of the last step. Local
    /// corrections set from planes ([`Self::start_local_from_planes`]) then follow the network.
    pub fn train(&mut self, steps: usize, lr: f32) -> FitLoss {
        if steps > 0 && self.planes_pending {
            // The corrections restored are those these distances gave: only keep them.
            self.set_plane_distance();
        }
        let mut loss = FitLoss::default();
        for _ in 0..steps {
            loss = self.step(lr);
        }
        if steps > 0 && !self.plane_distance.is_empty() {
            self.follow_planes();
        }
        loss
    }

    fn step(&mut self, lr: f32) -> FitLoss {
        let batch = self.draw_batch();
        let parts = self.block_losses(&batch);
        self.apply(parts, lr)
    }

    /// The queries and surface points of one Adam step, drawn from the fit's random stream:
    /// perturbation queries, then moved-source queries, then surface points, then a local
    /// model's queries.
    fn draw_batch(&mut self) -> Batch {
        let st = &self.settings;
        // The network of a local Φ whose corrections come from planes gives only the far field:
        // smaller batches (`LocalSettings::network_batch_divisor`).
        let divisor = if self.field.grid().is_some() && st.local.plane_fit {
            st.local.network_batch_divisor.max(1)
        } else {
            1
        };
        let (nq, ns) = if self.source_queries.is_empty() {
            (st.batch_queries, 0)
        } else {
            (st.refine_batch_queries, st.batch_source)
        };
        let (nq, ns) = ((nq / divisor).max(1), ns / divisor);
        let pools = self.pools.get_or_init(|| self.draw_pools().0);
        let (pool, local_pool) = (&pools.pool, &pools.local_pool);
        let nq = nq.min(pool.len());
        let nt = (st.batch_surface / divisor).max(1);
        let (wq, ws_) = (1.0 / nq.max(1) as f32, 1.0 / ns.max(1) as f32);
        let mut queries = Vec::with_capacity(nq + ns);
        for _ in 0..nq {
            let (x, t) = pool[self.rng.random_range(0..pool.len())];
            queries.push(Query { x, t, w: wq });
        }
        for _ in 0..ns {
            let (x, t) = self.source_queries[self.rng.random_range(0..self.source_queries.len())];
            queries.push(Query { x, t, w: ws_ });
        }
        let surface: Vec<[f32; 3]> = (0..nt)
            .map(|_| self.target[self.rng.random_range(0..self.target.len())])
            .collect();
        if !local_pool.is_empty() {
            let nl = st.local.batch;
            let wl = 1.0 / nl as f32;
            for _ in 0..nl {
                let (x, t) = local_pool[self.rng.random_range(0..local_pool.len())];
                queries.push(Query { x, t, w: wl });
            }
        }
        let we = st.lambda_eikonal / queries.len().max(1) as f32;
        let wsurf = st.lambda_surface / nt.max(1) as f32;
        Batch {
            queries,
            surface,
            nq,
            wq,
            we,
            wsurf,
        }
    }

    /// Each block's loss and projection loss, its parameter gradient left in its scratch (and
    /// its local part's `(slot, ∂L/∂θ)`): one task per block, in block order.
    fn block_losses(&mut self, batch: &Batch) -> Vec<(f64, f64)> {
        let Batch {
            ref queries,
            ref surface,
            nq,
            wq,
            we,
            wsurf,
        } = *batch;
        let field = &self.field;
        let train_local = self.trains_local();
        let mlp = field.mlp();
        let n_params = mlp.num_params();

        // One task per block; results come back in block order and are summed in that order,
        // so the step does not depend on the number of threads.
        let q_blocks: Vec<&[Query]> = queries.chunks(FIT_BLOCK).collect();
        let s_blocks: Vec<&[[f32; 3]]> = surface.chunks(FIT_BLOCK).collect();
        let tasks = q_blocks.len() + s_blocks.len();
        if self.scratch.len() < tasks {
            self.scratch
                .resize_with(tasks, || (mlp.workspace(), vec![0.0; n_params], Vec::new()));
        }
        self.scratch[..tasks]
            .par_iter_mut()
            .enumerate()
            .map(|(i, (ws, grad, local_grad))| {
                grad.fill(0.0);
                local_grad.clear();
                if i < q_blocks.len() {
                    let block = q_blocks[i];
                    let xs: Vec<[f32; 3]> = block.iter().map(|q| q.x).collect();
                    mlp.forward_block(&xs, true, ws);
                    let mut dphi = vec![0.0f32; block.len()];
                    let mut dgrad = vec![[0.0f32; 3]; block.len()];
                    let (mut total, mut proj) = (0.0f64, 0.0f64);
                    for (j, q) in block.iter().enumerate() {
                        let (mut phi, mut g) = (ws.value(j), ws.gradient(j));
                        field.add_local(&q.x, &mut phi, &mut g);
                        let (d2, l, dp, dg) = query_loss(&q.x, &q.t, q.w, we, phi, &g);
                        total += l as f64;
                        // The perturbation queries fill the first `nq` places of the batch.
                        if i * FIT_BLOCK + j < nq {
                            proj += d2 as f64 * wq as f64;
                        }
                        dphi[j] = dp;
                        dgrad[j] = dg;
                        if train_local {
                            field.local_adjoint(&q.x, dp, &dg, local_grad);
                        }
                    }
                    mlp.backward_block(ws, &dphi, &dgrad, grad);
                    (total, proj)
                } else {
                    let block = s_blocks[i - q_blocks.len()];
                    mlp.forward_block(block, false, ws);
                    let mut total = 0.0f64;
                    let dphi: Vec<f32> = (0..block.len())
                        .map(|j| {
                            let mut phi = ws.value(j);
                            field.add_local(&block[j], &mut phi, &mut [0.0; 3]);
                            total += (wsurf * phi.abs()) as f64;
                            let d = wsurf * phi.signum();
                            if train_local {
                                field.local_adjoint(&block[j], d, &[0.0; 3], local_grad);
                            }
                            d
                        })
                        .collect();
                    mlp.backward_block(ws, &dphi, &[], grad);
                    (total, 0.0)
                }
            })
            .collect()
    }

    /// Whether Adam trains the local corrections: a local Φ whose corrections are not set from
    /// planes (those are held, and their gradient is not computed).
    fn trains_local(&self) -> bool {
        self.field.grid().is_some() && !self.settings.local.plane_fit
    }

    /// Sums the blocks' losses and gradients in block order (so the step does not depend on
    /// the number of threads) and takes the Adam step at `lr`.
    fn apply(&mut self, parts: Vec<(f64, f64)>, lr: f32) -> FitLoss {
        let n_params = self.field.mlp().num_params();
        let mut grad = vec![0.0f32; n_params];
        let mut theta_grad = if self.trains_local() {
            vec![0.0f32; self.field.theta().len()]
        } else {
            Vec::new()
        };
        let mut loss = FitLoss::default();
        for ((total, proj), (_, g, lg)) in parts.into_iter().zip(&self.scratch) {
            loss.total += total;
            loss.projection += proj;
            for (a, b) in grad.iter_mut().zip(g) {
                *a += b;
            }
            for &(slot, d) in lg {
                theta_grad[slot as usize] += d;
            }
        }
        self.adam.step(self.field.mlp_mut().params_mut(), &grad, lr);
        if !theta_grad.is_empty() {
            let lr_local = lr * self.settings.local.lr_scale as f32;
            self.adam_local
                .step(self.field.theta_mut(), &theta_grad, lr_local);
        }
        loss
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on a sphere of radius 0.4 (unit frame).
    fn sphere(n: usize) -> Vec<[f32; 3]> {
        crate::sim::shapes::fibonacci_sphere(n)
            .iter()
            .map(|d| [0.4 * d.x as f32, 0.4 * d.z as f32, 0.4 * d.y as f32])
            .collect()
    }

    #[test]
    fn settings_written_before_the_local_kind_read_as_global() {
        let mut json = serde_json::to_value(FitSettings::default()).unwrap();
        json.as_object_mut().unwrap().remove("local");
        let old: FitSettings = serde_json::from_value(json).unwrap();
        assert_eq!(old.local.kind, crate::ModelKind::Global);
        let now: FitSettings =
            serde_json::from_value(serde_json::to_value(FitSettings::default()).unwrap()).unwrap();
        assert_eq!(now, FitSettings::default());
    }

    #[test]
    fn settings_written_before_the_batch_divisor_keep_their_batches() {
        let mut json = serde_json::to_value(FitSettings::default()).unwrap();
        let local = json["local"].as_object_mut().unwrap();
        assert!(local.remove("network_batch_divisor").is_some());
        let old: FitSettings = serde_json::from_value(json).unwrap();
        assert_eq!(old.local.network_batch_divisor, 1);
        assert_eq!(FitSettings::default().local.network_batch_divisor, 1);
    }

    #[test]
    fn a_restored_fitter_trains_to_the_same_bits_as_the_one_it_was_saved_from() {
        // A fitter set up for a restore draws its pools only when a step needs them, from the
        // seed's stream where `new` drew them: it must train to the same bits as the fitter
        // whose state it restored, global and local (corrections trained, with their own pool;
        // and corrections from planes, whose plane distances it computes again).
        let mut local = FitSettings::default();
        local.local.voxel = Some(0.05);
        local.local.plane_fit = false;
        let mut planes = local.clone();
        planes.local.plane_fit = true;
        let mut global = FitSettings::default();
        global.local.kind = crate::ModelKind::Global;
        global.local.voxel = None;
        for s in [&global, &local, &planes] {
            let mlp = MlpSettings::default();
            let mut original = SdfFitter::new(sphere(1500), &mlp, s, 9);
            original.train(3, 1e-3);
            let from_planes = s.local.plane_fit && s.local.voxel.is_some();
            if from_planes {
                let n = original.start_local_from_planes();
                assert!(n > 100, "{n} corners with a plane");
            }
            let mut restored = SdfFitter::for_restore(sphere(1500), &mlp, s, 9);
            assert!(restored.pools.get().is_none(), "pools drawn before a step");
            assert_eq!(restored.planes_pending, from_planes);
            restored.restore(original.state()).unwrap();
            original.train(4, 1e-3);
            restored.train(4, 1e-3);
            assert_eq!(
                original
                    .plane_distance
                    .iter()
                    .map(|d| d.to_bits())
                    .collect::<Vec<_>>(),
                restored
                    .plane_distance
                    .iter()
                    .map(|d| d.to_bits())
                    .collect::<Vec<_>>()
            );
            let pools = (original.pools.get().unwrap(), restored.pools.get().unwrap());
            assert_eq!(pools.0.pool, pools.1.pool);
            assert_eq!(pools.0.local_pool, pools.1.local_pool);
            let trained = s.local.voxel.is_some() && !s.local.plane_fit;
            assert_eq!(pools.1.local_pool.is_empty(), !trained);
            let (a, b) = (original.state(), restored.state());
            assert!(a
                .params
                .iter()
                .zip(&b.params)
                .all(|(x, y)| x.to_bits() == y.to_bits()));
            assert_eq!(a.rng_word_pos, b.rng_word_pos);
        }
    }

    #[test]
    fn a_local_network_from_planes_draws_divided_batches_and_others_do_not() {
        let mut s = FitSettings::default();
        s.local.voxel = Some(0.05);
        s.local.network_batch_divisor = 4;
        let counts = |s: &FitSettings| {
            let mut f = SdfFitter::new(sphere(2000), &MlpSettings::default(), s, 1);
            let b = f.draw_batch();
            (b.nq, b.queries.len(), b.surface.len())
        };
        // Local, corrections from planes: a quarter of 256 perturbation queries and of 128
        // surface points.
        assert_eq!(counts(&s), (64, 64, 32));
        // Corrections trained by Adam: the network's batches whole, and the local queries.
        let mut trained = s.clone();
        trained.local.plane_fit = false;
        assert_eq!(counts(&trained), (256, 256 + 2048, 128));
        // A global Φ: whole.
        let mut global = s.clone();
        global.local.kind = crate::ModelKind::Global;
        global.local.voxel = None;
        assert_eq!(counts(&global), (256, 256, 128));
        // Refinement: moved-source queries divided too.
        let mut f = SdfFitter::new(sphere(2000), &MlpSettings::default(), &s, 1);
        f.add_source_queries(&sphere(100));
        let b = f.draw_batch();
        assert_eq!((b.nq, b.queries.len(), b.surface.len()), (32, 64, 32));
        // By default a scene's network takes the batches a quarter of the former ones made
        // (1024, 512, 512 and 512 divided by 4).
        s.local.network_batch_divisor = 1;
        assert_eq!(counts(&s), (256, 256, 128));
    }

    #[test]
    fn query_loss_derivatives_match_finite_differences() {
        let (x, t) = ([0.3f32, -0.2, 0.5], [0.25f32, -0.1, 0.42]);
        for (phi, g) in [
            (0.07f32, [0.5f32, -0.9, 0.3]),
            (-0.02, [0.1, 0.2, -1.3]),
            (0.2, [1.5, 0.0, 0.1]),
        ] {
            let (_, _, dphi, dg) = query_loss(&x, &t, 0.7, 0.05, phi, &g);
            let h = 1e-3f32;
            let f = |p: f32, gg: [f32; 3]| query_loss(&x, &t, 0.7, 0.05, p, &gg).1 as f64;
            let fd_phi = (f(phi + h, g) - f(phi - h, g)) / (2.0 * h as f64);
            assert!(
                (fd_phi - dphi as f64).abs() < 1e-3,
                "∂/∂Φ: {fd_phi} vs {dphi}"
            );
            for k in 0..3 {
                let (mut a, mut b) = (g, g);
                a[k] += h;
                b[k] -= h;
                let fd = (f(phi, a) - f(phi, b)) / (2.0 * h as f64);
                assert!(
                    (fd - dg[k] as f64).abs() < 1e-3,
                    "∂/∂g{k}: {fd} vs {}",
                    dg[k]
                );
            }
        }
    }

    #[test]
    fn projection_loss_counts_only_perturbation_queries() {
        // Equal perturbation and source batches give equal weights: the split must not rely on them.
        let settings = FitSettings {
            batch_queries: 512,
            refine_batch_queries: 512,
            batch_source: 512,
            ..Default::default()
        };
        let target = sphere(512);
        let plain = SdfFitter::new(target.clone(), &MlpSettings::default(), &settings, 4);
        let mut with_source = plain.clone();
        // Far from the surface, so counting them would change the sum a lot.
        let far: Vec<[f32; 3]> = target
            .iter()
            .map(|p| [p[0] * 2.0, p[1] * 2.0, p[2] * 2.0])
            .collect();
        with_source.add_source_queries(&far);
        let a = plain.clone().train(1, 1e-3);
        let b = with_source.train(1, 1e-3);
        assert_eq!(a.projection, b.projection);
        assert!(
            b.total > a.total,
            "source queries must add to the total loss"
        );
    }

    #[test]
    fn fitted_sdf_of_a_sphere_is_close_to_the_true_distance() {
        let target = sphere(1024);
        let mut fit = SdfFitter::new(
            target.clone(),
            &MlpSettings::default(),
            &FitSettings::default(),
            1,
        );
        let first = fit.train(1, 2e-3);
        let last = fit.train(300, 2e-3);
        assert!(
            last.projection < first.projection * 0.5,
            "loss {first:?} → {last:?}"
        );
        // On the surface and at ±0.05 along the normal.
        let mut worst: f32 = 0.0;
        for p in target.iter().step_by(37) {
            for off in [-0.05f32, 0.0, 0.05] {
                let s = (0.4 + off) / 0.4;
                let (v, _) = fit.mlp().eval(&[[p[0] * s, p[1] * s, p[2] * s]], false);
                worst = worst.max((v[0] - off).abs());
            }
        }
        assert!(worst < 0.02, "worst |Φ − d| near the sphere = {worst}");
    }

    #[test]
    fn the_learned_start_fits_unseen_objects_in_fewer_steps_than_the_sphere() {
        // Objects the initialisation was not learned on (another random stream), turned so
        // their unit frames differ from the canonical one.
        let mut rng = ChaCha8Rng::seed_from_u64(2026);
        let fit = FitSettings::default();
        let (mut learned_150, mut sphere_150, mut sphere_250) = (0.0, 0.0, 0.0);
        let objects = 6;
        for k in 0..objects {
            let turn = nalgebra::Rotation3::new(nalgebra::Vector3::new(0.7, -0.3, 0.5) * k as f64);
            let points: Vec<_> = crate::sim::shapes::assembly(4000, &mut rng)
                .iter()
                .map(|p| turn * p)
                .collect();
            let norm = crate::geometry::cloud::Normalization::from_target(&points).unwrap();
            let unit: Vec<[f32; 3]> = points.iter().map(|p| norm.to_unit(p)).collect();
            for learned_init in [true, false] {
                let mut fitter = SdfFitter::new(unit.clone(), &MlpSettings::default(), &fit, k);
                if learned_init {
                    let init = crate::field::learned_init::shipped().unwrap();
                    fitter.restart_from(&init.params).unwrap();
                }
                fitter.train(150, fit.prefit_lr);
                let at_150 = fitter.quality(2000, 1).on_target / objects as f64;
                if learned_init {
                    learned_150 += at_150;
                } else {
                    sphere_150 += at_150;
                    fitter.train(100, fit.prefit_lr);
                    sphere_250 += fitter.quality(2000, 1).on_target / objects as f64;
                }
            }
        }
        // Mean |Φ| on the objects' points, normalised units.
        assert!(
            learned_150 < 0.8 * sphere_150 && learned_150 < sphere_250,
            "after 150 steps learned {learned_150:.5}, sphere {sphere_150:.5}; sphere after 250 {sphere_250:.5}"
        );
    }
}
