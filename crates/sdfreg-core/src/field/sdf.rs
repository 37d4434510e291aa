//! The fitted Φ: the MLP and, for a local model, its grid of corrections.

use crate::field::local_grid::LocalGrid;
use crate::field::mlp::Mlp;
use crate::field::Field;

/// The fitted Φ: the MLP, plus for a local model the sparse grid of corrections near the
/// target's points ([`crate::field::local_grid`]): `Φ(x) = Φ_mlp(x) + h Σ w_c(x) θ_c`.
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
