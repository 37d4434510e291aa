//! What the solver registers against: a distance field Φ of the target in its unit frame
//! ([`Field`]) — the fitted MLP ([`crate::mlp::Mlp`]) or a mesh's exact distance
//! ([`crate::mesh_field::MeshField`]) — together with the target points the polish and the
//! quality figures use (`Surface`, within the crate).

use rayon::prelude::*;

use crate::local_grid::LocalGrid;
use crate::mlp::{with_workspace, Mlp, BLOCK};
use crate::sdf_fit::{SdfFitter, Tree};

/// A distance field of the target, unit frame (the target's largest bounding-box side is 1):
/// the value Φ(x), zero on the surface, and its gradient.
pub trait Field: Sync {
    /// Φ at each of `xs` (at most [`BLOCK`] points) into `values` and, when asked, ∇Φ into
    /// `gradients` (both cleared first).
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        gradients: Option<&mut Vec<[f32; 3]>>,
    );

    /// Φ (and ∇Φ when `gradients`, else an empty vector) at any number of points, in parallel.
    fn eval_points(&self, xs: &[[f32; 3]], gradients: bool) -> (Vec<f32>, Vec<[f32; 3]>) {
        let parts: Vec<(Vec<f32>, Vec<[f32; 3]>)> = xs
            .par_chunks(BLOCK)
            .map(|chunk| {
                let (mut v, mut g) = (Vec::new(), Vec::new());
                self.eval_block(chunk, &mut v, gradients.then_some(&mut g));
                (v, g)
            })
            .collect();
        let mut values = Vec::with_capacity(xs.len());
        let mut grads = Vec::with_capacity(if gradients { xs.len() } else { 0 });
        for (v, g) in parts {
            values.extend(v);
            grads.extend(g);
        }
        (values, grads)
    }
}

impl Field for Mlp {
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        gradients: Option<&mut Vec<[f32; 3]>>,
    ) {
        with_workspace(|ws| {
            self.forward_block(xs, gradients.is_some(), ws);
            values.clear();
            values.extend((0..xs.len()).map(|j| ws.value(j)));
            if let Some(g) = gradients {
                g.clear();
                g.extend((0..xs.len()).map(|j| ws.gradient(j)));
            }
        })
    }
}

/// The fitted Φ: the MLP, plus for a local model the sparse grid of corrections near the
/// target's points ([`crate::local_grid`]): `Φ(x) = Φ_mlp(x) + h Σ w_c(x) θ_c`.
#[derive(Clone, Debug)]
pub struct SdfField {
    mlp: Mlp,
    grid: Option<LocalGrid>,
    /// The corrections θ (in voxels), one per grid corner; empty without a grid.
    theta: Vec<f32>,
}

impl SdfField {
    /// Φ from a network and, for a local model, a grid (its corrections start at 0).
    pub fn new(mlp: Mlp, grid: Option<LocalGrid>) -> Self {
        let theta = vec![0.0; grid.as_ref().map_or(0, LocalGrid::len)];
        Self { mlp, grid, theta }
    }

    /// The network (Φ's global part).
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }

    pub(crate) fn mlp_mut(&mut self) -> &mut Mlp {
        &mut self.mlp
    }

    /// The grid of the local part; `None` for a global model.
    pub fn grid(&self) -> Option<&LocalGrid> {
        self.grid.as_ref()
    }

    /// The local corrections (in voxels), one per grid corner.
    pub fn theta(&self) -> &[f32] {
        &self.theta
    }

    pub(crate) fn theta_mut(&mut self) -> &mut [f32] {
        &mut self.theta
    }

    /// Adds the local part's value and gradient at `x` to `phi` and `grad` (nothing for a
    /// global model).
    #[inline]
    pub(crate) fn add_local(&self, x: &[f32; 3], phi: &mut f32, grad: &mut [f32; 3]) {
        if let Some(grid) = &self.grid {
            let (v, g) = grid.eval(&self.theta, x);
            *phi += v;
            for a in 0..3 {
                grad[a] += g[a];
            }
        }
    }

    /// Pushes `∂L/∂θ` for a loss with `∂L/∂Φ(x) = dphi`, `∂L/∂∇Φ(x) = dgrad` (nothing for a
    /// global model).
    #[inline]
    pub(crate) fn local_adjoint(
        &self,
        x: &[f32; 3],
        dphi: f32,
        dgrad: &[f32; 3],
        out: &mut Vec<(u32, f32)>,
    ) {
        if let Some(grid) = &self.grid {
            grid.adjoint(x, dphi, dgrad, out);
        }
    }
}

impl Field for SdfField {
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        mut gradients: Option<&mut Vec<[f32; 3]>>,
    ) {
        self.mlp.eval_block(xs, values, gradients.as_deref_mut());
        if self.grid.is_some() {
            for (j, x) in xs.iter().enumerate() {
                let mut unused = [0.0; 3];
                let g = match gradients.as_deref_mut() {
                    Some(gs) => &mut gs[j],
                    None => &mut unused,
                };
                self.add_local(x, &mut values[j], g);
            }
        }
    }
}

/// The target as the registration stages use it: Φ, the (subsampled) target points in the unit
/// frame and their k-d tree; refinable when Φ is fitted.
pub(crate) trait Surface: Clone + Sync {
    /// The distance field.
    type Phi: Field;
    /// The field of the multi-start's first round: Φ itself, or Φ baked into a grid when Φ is
    /// frozen ([`crate::grid_field`]).
    type Coarse: Field;
    /// Φ.
    fn phi(&self) -> &Self::Phi;
    /// The multi-start's field.
    fn coarse(&self) -> &Self::Coarse;
    /// Target points, unit frame.
    fn target(&self) -> &[[f32; 3]];
    /// Their k-d tree.
    fn tree(&self) -> &Tree;
    /// Adds moved-source queries for a refinement of Φ (coarse-to-fine); an exact field has
    /// nothing to refine and ignores them.
    fn add_source_queries(&mut self, points: &[[f32; 3]]);
    /// Refines Φ for `steps` Adam steps at `lr`; an exact field ignores it.
    fn refine(&mut self, steps: usize, lr: f32);
    /// Whether Φ is a local model (a scene, [`crate::ModelKind::Local`]).
    fn is_local(&self) -> bool {
        false
    }
    /// The planes at the target's points of `k` points each, for a scene's polish: new ones,
    /// or a stored model's kept from earlier registrations.
    fn target_planes(&self, k: usize) -> std::sync::Arc<crate::polish::TargetPlanes> {
        std::sync::Arc::new(crate::polish::TargetPlanes::new(
            self.target(),
            self.tree(),
            k,
        ))
    }
}

impl Surface for SdfFitter {
    type Phi = SdfField;
    type Coarse = SdfField;
    fn phi(&self) -> &SdfField {
        self.field()
    }
    fn coarse(&self) -> &SdfField {
        self.field()
    }
    fn target(&self) -> &[[f32; 3]] {
        SdfFitter::target(self)
    }
    fn tree(&self) -> &Tree {
        SdfFitter::tree(self)
    }
    fn add_source_queries(&mut self, points: &[[f32; 3]]) {
        SdfFitter::add_source_queries(self, points)
    }
    fn refine(&mut self, steps: usize, lr: f32) {
        self.train(steps, lr);
    }
    fn is_local(&self) -> bool {
        self.field().grid().is_some()
    }
}

/// Φ (user units) and ∇Φ at `points` (user units and frame) of a field in the unit frame of
/// `norm`, in parallel.
pub(crate) fn evaluate_user<F: Field + ?Sized>(
    norm: &crate::cloud::Normalization,
    field: &F,
    points: &[nalgebra::Point3<f64>],
) -> (Vec<f64>, Vec<nalgebra::Vector3<f64>>) {
    let unit: Vec<[f32; 3]> = points.iter().map(|p| norm.to_unit(p)).collect();
    let (phi, grad) = field.eval_points(&unit, true);
    let phi = phi.iter().map(|&v| v as f64 * norm.scale).collect();
    let grad = grad
        .iter()
        .map(|g| nalgebra::Vector3::new(g[0] as f64, g[1] as f64, g[2] as f64))
        .collect();
    (phi, grad)
}

/// The closest surface point of each of `points` (user units and frame), `p − Φ ∇Φ/‖∇Φ‖`, with
/// `(Φ, ∇Φ)` from [`evaluate_user`].
pub(crate) fn closest_user(
    points: &[nalgebra::Point3<f64>],
    (phi, grad): (Vec<f64>, Vec<nalgebra::Vector3<f64>>),
) -> Vec<nalgebra::Point3<f64>> {
    points
        .iter()
        .zip(phi.iter().zip(&grad))
        .map(|(p, (d, g))| p - g.normalize() * *d)
        .collect()
}
