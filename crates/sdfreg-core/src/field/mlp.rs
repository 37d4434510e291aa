//! The neural SDF Φ: a softplus MLP `R³ → R` with hand-written first and second derivatives.
//!
//! Layout: `3 → width → … → width → 1` with `depth` hidden layers, softplus activations
//! `sp(z) = log(1 + exp(βz)) / β` (β = 100 by default, close to a ReLU but smooth, so ∇Φ is
//! continuous), f32 parameters in one flat vector (weights column-major, `out × in`, then bias,
//! layer by layer) so the optimiser can treat them as one array.
//!
//! Forward mode: a block of `B` points is processed as one matrix whose columns are the primal
//! inputs and (optionally) the three input tangents `∂/∂x_k` of every point, `[H | dH₁ | dH₂ | dH₃]`.
//! Every layer is then one dense product with faer. The output row holds `Φ` and `∇Φ`.
//! Reverse mode ([`Mlp::backward_block`]) takes `∂L/∂Φ` and `∂L/∂∇Φ` per point and accumulates
//! the parameter gradient; because `∇Φ` is itself a forward-mode derivative, this is the
//! second-order (double-backward) pass the fitting losses need (paper eq. 18, 19).
//!
//! Entry points: [`Mlp::new`], [`Mlp::eval`], [`Mlp::forward_block`], [`Mlp::backward_block`].

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use rand::Rng;
use rand_distr::{Distribution, Normal};

use crate::field::activation::kernels;
use crate::field::Field;

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

/// Architecture and initialisation of the SDF network.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MlpSettings {
    /// Neurons per hidden layer. Default 32 (wider nets fit the noise of real clouds).
    pub width: usize,
    /// Number of hidden layers. Default 3.
    pub depth: usize,
    /// Softplus sharpness β (1 / normalised length units). Default 100.
    pub beta: f32,
    /// Radius of the sphere the geometric initialisation starts from, in normalised units
    /// (the target's largest bounding-box side is 1). Default 0.3.
    pub init_radius: f32,
    /// A full call's pre-fit of an object's Φ ([`crate::FitSettings::prefit_steps`]) starts
    /// from the initialisation learned offline on procedural objects
    /// ([`crate::field::learned_init`]) instead of the sphere. Default false; the `learned`
    /// preset ([`crate::RegisterSettings::learned`]) sets it with a shorter pre-fit. Only a
    /// network of the architecture it was learned for (width 32, depth 3, β 100) has one; any
    /// other starts from the sphere, and so do a stored model's pre-fit, a scene's local Φ and
    /// a fit with a scale (`RegisterSettings::starts_learned`; fitted from it as global Φs,
    /// the sparse procedural rooms of `align`'s tests ended 0.5° off). After 150 Adam steps from
    /// it, Φ on unseen objects is nearer their points than after 250 from the sphere (mean |Φ|
    /// on ModelNet's shapes 0.0055 against 0.0078). Settings written before it existed read
    /// false.
    #[serde(default)]
    pub learned_init: bool,
}

impl MlpSettings {
    /// Checks every field; the error names it (`mlp.width`, …).
    pub fn validate(&self) -> Result<(), crate::base::error::Error> {
        use crate::base::check;
        check::count_at_least("mlp.width", self.width, 1)?;
        check::count_at_least("mlp.depth", self.depth, 1)?;
        check::positive("mlp.beta", self.beta as f64)?;
        check::positive("mlp.init_radius", self.init_radius as f64)
    }
}

impl Default for MlpSettings {
    fn default() -> Self {
        Self {
            width: 32,
            depth: 3,
            beta: 100.0,
            init_radius: 0.3,
            learned_init: false,
        }
    }
}

/// Where one layer's weights and bias sit in the flat parameter vector.
#[derive(Clone, Copy, Debug)]
struct Layer {
    n_in: usize,
    n_out: usize,
    w: usize,
    b: usize,
}

thread_local! {
    static WORKSPACE: std::cell::RefCell<Workspace> = std::cell::RefCell::new(Workspace::default());
}

/// Runs `f` with this thread's scratch [`Workspace`], so short parallel evaluations (LM steps,
/// multi-start candidates) allocate nothing. `f` must not start parallel work itself: a task
/// stolen while it waits could ask for the same workspace.
pub fn with_workspace<R>(f: impl FnOnce(&mut Workspace) -> R) -> R {
    WORKSPACE.with(|w| f(&mut w.borrow_mut()))
}

/// A softplus MLP signed distance function. Input and output are in normalised units.
#[derive(Clone, Debug)]
pub struct Mlp {
    layers: Vec<Layer>,
    params: Vec<f32>,
    beta: f32,
    width: usize,
}

/// Scratch buffers for one block of points; reused between calls (see [`Mlp::workspace`]).
#[derive(Clone, Debug, Default)]
pub struct Workspace {
    /// Points in this block.
    b: usize,
    /// Tangent directions carried (0 or 3).
    t: usize,
    x: Vec<f32>,
    /// Pre-activations per hidden layer, `width × (1+t)B`.
    z: Vec<Vec<f32>>,
    /// Post-activations per hidden layer, `width × (1+t)B`.
    h: Vec<Vec<f32>>,
    /// σ(βz) per hidden layer, `width × B`.
    s: Vec<Vec<f32>>,
    /// Network output, `(1+t)B`: Φ then ∂Φ/∂x, ∂Φ/∂y, ∂Φ/∂z, each a run of B values.
    out: Vec<f32>,
    hbar: Vec<f32>,
    zbar: Vec<f32>,
    sbar: Vec<f32>,
}

impl Workspace {
    /// Φ of point `j` of the last forward pass.
    #[inline]
    pub fn value(&self, j: usize) -> f32 {
        self.out[j]
    }
    /// ∇Φ of point `j` of the last forward pass (needs tangents).
    #[inline]
    pub fn gradient(&self, j: usize) -> [f32; 3] {
        let b = self.b;
        [self.out[b + j], self.out[2 * b + j], self.out[3 * b + j]]
    }
    /// Points in the last forward pass.
    pub fn len(&self) -> usize {
        self.b
    }
    /// Whether the last forward pass had no points.
    pub fn is_empty(&self) -> bool {
        self.b == 0
    }
}

fn mat(data: &[f32], rows: usize, cols: usize) -> MatRef<'_, f32> {
    MatRef::from_column_major_slice(data, rows, cols)
}

fn mat_mut(data: &mut [f32], rows: usize, cols: usize) -> MatMut<'_, f32> {
    MatMut::from_column_major_slice_mut(data, rows, cols)
}

/// Sizes a scratch buffer; its contents are overwritten by the caller, so no zero-fill.
fn resize(v: &mut Vec<f32>, n: usize) {
    if v.len() != n {
        v.resize(n, 0.0);
    }
}

impl Mlp {
    /// A network with geometric (sphere) initialisation (Atzmon & Lipman, SAL): Φ(x) ≈ |x| − r
    /// at start, so the far field points the right way before any fitting. (A full call's
    /// pre-fit then restarts it from [`crate::field::learned_init`] when
    /// [`MlpSettings::learned_init`] asks.)
    pub fn new<R: Rng>(settings: &MlpSettings, rng: &mut R) -> Self {
        let (w, d) = (settings.width.max(1), settings.depth.max(1));
        let (layers, n) = Self::layout(w, d);
        let mut params = vec![0.0f32; n];
        let last = layers.len() - 1;
        for (i, l) in layers.iter().enumerate() {
            let dist = if i == last {
                Normal::new((std::f32::consts::PI / l.n_in as f32).sqrt(), 1e-5).unwrap()
            } else {
                Normal::new(0.0, (2.0 / l.n_out as f32).sqrt()).unwrap()
            };
            for p in &mut params[l.w..l.b] {
                *p = dist.sample(rng);
            }
            if i == last {
                params[l.b] = -settings.init_radius;
            }
        }
        Self {
            layers,
            params,
            beta: settings.beta,
            width: w,
        }
    }

    /// The layers of a network `3 → width × depth → 1` and its number of parameters.
    fn layout(width: usize, depth: usize) -> (Vec<Layer>, usize) {
        let mut dims = vec![3];
        dims.extend(std::iter::repeat_n(width, depth));
        dims.push(1);
        let mut layers = Vec::new();
        let mut n = 0;
        for pair in dims.windows(2) {
            let (n_in, n_out) = (pair[0], pair[1]);
            layers.push(Layer {
                n_in,
                n_out,
                w: n,
                b: n + n_in * n_out,
            });
            n += n_in * n_out + n_out;
        }
        (layers, n)
    }

    /// Number of parameters of a network `3 → width × depth → 1` ([`Self::num_params`] of
    /// one built with these sizes).
    pub fn param_count(width: usize, depth: usize) -> usize {
        Self::layout(width, depth).1
    }

    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.params.len()
    }
    /// The flat parameter vector.
    pub fn params(&self) -> &[f32] {
        &self.params
    }
    /// The flat parameter vector, for the optimiser.
    pub fn params_mut(&mut self) -> &mut [f32] {
        &mut self.params
    }
    /// An empty workspace sized on first use.
    pub fn workspace(&self) -> Workspace {
        Workspace::default()
    }

    fn weights(&self, l: &Layer) -> MatRef<'_, f32> {
        mat(&self.params[l.w..l.b], l.n_out, l.n_in)
    }

    /// Forward pass for one block of points. `tangents`: also compute ∇Φ (and keep what
    /// [`Mlp::backward_block`] needs for losses on ∇Φ). Results are read with
    /// [`Workspace::value`] and [`Workspace::gradient`].
    pub fn forward_block(&self, points: &[[f32; 3]], tangents: bool, ws: &mut Workspace) {
        let b = points.len();
        let t = if tangents { 3 } else { 0 };
        let nc = (1 + t) * b;
        let w = self.width;
        let hidden = self.layers.len() - 1;
        ws.b = b;
        ws.t = t;
        ws.z.resize_with(hidden, Vec::new);
        ws.h.resize_with(hidden, Vec::new);
        ws.s.resize_with(hidden, Vec::new);
        resize(&mut ws.x, 3 * b);
        for (j, p) in points.iter().enumerate() {
            ws.x[3 * j..3 * j + 3].copy_from_slice(p);
        }
        let beta = self.beta;
        for li in 0..hidden {
            let l = self.layers[li];
            let (z_all, rest) = ws.z.split_at_mut(li + 1);
            let z = &mut z_all[li];
            resize(z, w * nc);
            if li == 0 {
                // Primal: W₀ x. Tangent k of the input is e_k, so its pre-activation is column k of W₀.
                matmul(
                    mat_mut(&mut z[..w * b], w, b),
                    Accum::Replace,
                    self.weights(&l),
                    mat(&ws.x, 3, b),
                    1.0,
                    Par::Seq,
                );
                let w0 = &self.params[l.w..l.b];
                for k in 0..t {
                    let col = &w0[k * w..(k + 1) * w];
                    for j in 0..b {
                        let o = (1 + k) * b * w + j * w;
                        z[o..o + w].copy_from_slice(col);
                    }
                }
            } else {
                let hp = &ws.h[li - 1];
                matmul(
                    mat_mut(z, w, nc),
                    Accum::Replace,
                    self.weights(&l),
                    mat(hp, w, nc),
                    1.0,
                    Par::Seq,
                );
            }
            let _ = rest;
            let bias = &self.params[l.b..l.b + w];
            let h = &mut ws.h[li];
            let s = &mut ws.s[li];
            resize(h, w * nc);
            resize(s, w * b);
            kernels::activate(&mut z[..w * b], &mut h[..w * b], s, bias, beta);
            for k in 0..t {
                let o = (1 + k) * b * w;
                kernels::mul(&mut h[o..o + b * w], &z[o..o + b * w], s);
            }
        }
        let l = self.layers[hidden];
        resize(&mut ws.out, nc);
        matmul(
            mat_mut(&mut ws.out, 1, nc),
            Accum::Replace,
            self.weights(&l),
            mat(&ws.h[hidden - 1], w, nc),
            1.0,
            Par::Seq,
        );
        let b_out = self.params[l.b];
        for v in &mut ws.out[..b] {
            *v += b_out;
        }
    }

    /// Reverse pass after [`Mlp::forward_block`]: given `dphi[j] = ∂L/∂Φ(x_j)` and (when the
    /// forward pass carried tangents) `dgrad[j] = ∂L/∂∇Φ(x_j)`, adds `∂L/∂θ` to `grad`
    /// (same layout as [`Mlp::params`]).
    pub fn backward_block(
        &self,
        ws: &mut Workspace,
        dphi: &[f32],
        dgrad: &[[f32; 3]],
        grad: &mut [f32],
    ) {
        let (b, t, w) = (ws.b, ws.t, self.width);
        let nc = (1 + t) * b;
        let hidden = self.layers.len() - 1;
        let beta = self.beta;
        debug_assert_eq!(dphi.len(), b);
        // Adjoint of the output row: [∂L/∂Φ | ∂L/∂∇Φ_x | ∂L/∂∇Φ_y | ∂L/∂∇Φ_z].
        let mut obar = vec![0.0f32; nc];
        obar[..b].copy_from_slice(dphi);
        for k in 0..t {
            for j in 0..b {
                obar[(1 + k) * b + j] = dgrad[j][k];
            }
        }
        let l = self.layers[hidden];
        {
            let (gw, gb) = grad[l.w..].split_at_mut(l.b - l.w);
            matmul(
                mat_mut(gw, 1, w),
                Accum::Add,
                mat(&obar, 1, nc),
                mat(&ws.h[hidden - 1], w, nc).transpose(),
                1.0,
                Par::Seq,
            );
            gb[0] += obar[..b].iter().sum::<f32>();
        }
        // hbar = w_outᵀ obar (an outer product).
        resize(&mut ws.hbar, w * nc);
        let w_out = &self.params[l.w..l.b];
        for (c, &o) in obar.iter().enumerate() {
            for (hb, &wo) in ws.hbar[c * w..(c + 1) * w].iter_mut().zip(w_out) {
                *hb = wo * o;
            }
        }
        resize(&mut ws.zbar, w * nc);
        for li in (0..hidden).rev() {
            let l = self.layers[li];
            let (s, z) = (&ws.s[li], &ws.z[li]);
            // Tangent adjoints: dh_k = s ⊙ dz_k ⇒ z̄_k = h̄_k ⊙ s, and s̄ = Σ_k h̄_k ⊙ dz_k.
            // h = sp(z) ⇒ z̄ += h̄ σ; σ = σ(βz) ⇒ z̄ += s̄ β σ (1 − σ).
            let (zb_p, zb_t) = ws.zbar.split_at_mut(w * b);
            let (hb_p, hb_t) = ws.hbar.split_at(w * b);
            resize(&mut ws.sbar, w * b);
            ws.sbar.fill(0.0);
            for k in 0..t {
                let o = k * b * w;
                kernels::mul_add(
                    &mut ws.sbar,
                    &hb_t[o..o + b * w],
                    &z[w * b + o..w * b + o + b * w],
                );
                kernels::mul(&mut zb_t[o..o + b * w], &hb_t[o..o + b * w], s);
            }
            kernels::primal_adjoint(zb_p, hb_p, s, &ws.sbar, beta);
            let (gw, gb) = grad[l.w..].split_at_mut(l.b - l.w);
            kernels::add_columns(&mut gb[..w], zb_p);
            if li == 0 {
                // Input tangents are constants e_k: W₀ gets z̄ xᵀ plus Σ_j z̄_k in column k.
                matmul(
                    mat_mut(gw, w, 3),
                    Accum::Add,
                    mat(&ws.zbar[..w * b], w, b),
                    mat(&ws.x, 3, b).transpose(),
                    1.0,
                    Par::Seq,
                );
                for k in 0..t {
                    let o = (1 + k) * b * w;
                    kernels::add_columns(&mut gw[k * w..(k + 1) * w], &ws.zbar[o..o + b * w]);
                }
            } else {
                matmul(
                    mat_mut(gw, w, w),
                    Accum::Add,
                    mat(&ws.zbar, w, nc),
                    mat(&ws.h[li - 1], w, nc).transpose(),
                    1.0,
                    Par::Seq,
                );
                matmul(
                    mat_mut(&mut ws.hbar, w, nc),
                    Accum::Replace,
                    self.weights(&l).transpose(),
                    mat(&ws.zbar, w, nc),
                    1.0,
                    Par::Seq,
                );
            }
        }
    }

    /// Φ (and ∇Φ when `gradients`) at `points` (normalised units), in parallel over blocks of
    /// [`BLOCK`](crate::field::BLOCK) points on the current rayon pool. Returns `(values, gradients)`; gradients is
    /// empty when not asked for.
    pub fn eval(&self, points: &[[f32; 3]], gradients: bool) -> (Vec<f32>, Vec<[f32; 3]>) {
        crate::field::Field::eval_points(self, points, gradients)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::BLOCK;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn small_net(beta: f32, seed: u64) -> Mlp {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut net = Mlp::new(
            &MlpSettings {
                width: 8,
                depth: 3,
                beta,
                init_radius: 0.3,
                learned_init: false,
            },
            &mut rng,
        );
        // Perturb all parameters so no term is trivially zero (e.g. biases at init).
        for p in net.params_mut() {
            *p += rng.random_range(-0.3..0.3);
        }
        net
    }

    fn points(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                [
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                    rng.random_range(-0.6..0.6),
                ]
            })
            .collect()
    }

    #[test]
    fn sphere_initialisation_approximates_distance_to_sphere() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let net = Mlp::new(&MlpSettings::default(), &mut rng);
        assert_eq!(net.num_params(), 3 * 32 + 32 + 2 * (32 * 32 + 32) + 32 + 1);
        assert_eq!(Mlp::param_count(32, 3), net.num_params());
        let pts: Vec<[f32; 3]> = points(200, 4)
            .into_iter()
            .filter(|p| p.iter().map(|v| v * v).sum::<f32>() > 0.05)
            .collect();
        let (v, g) = net.eval(&pts, true);
        // Geometric init is only approximately a sphere; it must point outwards with |∇Φ| ≈ 1.
        let mut cos_sum = 0.0;
        for (p, gi) in pts.iter().zip(&g) {
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
            let gn = (gi[0] * gi[0] + gi[1] * gi[1] + gi[2] * gi[2]).sqrt();
            cos_sum += (gi[0] * p[0] + gi[1] * p[1] + gi[2] * p[2]) / (gn * r);
        }
        let mean_cos = cos_sum / pts.len() as f32;
        assert!(mean_cos > 0.8, "mean cos(∇Φ, x) = {mean_cos}");
        let err: f32 = pts
            .iter()
            .zip(&v)
            .map(|(p, &vi)| (vi - ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.3)).abs())
            .sum::<f32>()
            / pts.len() as f32;
        assert!(err < 0.15, "mean |Φ − (|x| − r)| = {err}");
    }

    #[test]
    fn input_gradient_matches_finite_differences() {
        let net = small_net(10.0, 1);
        let pts = points(40, 2);
        let (_, g) = net.eval(&pts, true);
        let h = 1e-2f32;
        let mut worst = 0.0f32;
        for (p, gi) in pts.iter().zip(&g) {
            for k in 0..3 {
                let (mut a, mut b) = (*p, *p);
                a[k] += h;
                b[k] -= h;
                let (va, _) = net.eval(&[a], false);
                let (vb, _) = net.eval(&[b], false);
                let fd = (va[0] - vb[0]) / (2.0 * h);
                worst = worst.max((fd - gi[k]).abs() / (1.0 + gi[k].abs()));
            }
        }
        assert!(worst < 2e-3, "worst relative mismatch {worst}");
    }

    /// A scalar loss that touches Φ and ∇Φ nonlinearly: Σ_j (a_j Φ_j + Φ_j² + c_j·∇Φ_j + |∇Φ_j|²).
    fn test_loss(net: &Mlp, pts: &[[f32; 3]], tangents: bool) -> (f64, Vec<f32>) {
        let mut ws = net.workspace();
        net.forward_block(pts, tangents, &mut ws);
        let mut loss = 0.0f64;
        let mut dphi = vec![0.0; pts.len()];
        let mut dgrad = vec![[0.0; 3]; pts.len()];
        for j in 0..pts.len() {
            let a = 0.3 + 0.1 * j as f32;
            let phi = ws.value(j);
            loss += (a * phi + phi * phi) as f64;
            dphi[j] = a + 2.0 * phi;
            if tangents {
                let g = ws.gradient(j);
                for k in 0..3 {
                    let c = 0.2 * (k as f32 + 1.0) - 0.05 * j as f32;
                    loss += (c * g[k] + g[k] * g[k]) as f64;
                    dgrad[j][k] = c + 2.0 * g[k];
                }
            }
        }
        let mut grad = vec![0.0; net.num_params()];
        net.backward_block(&mut ws, &dphi, &dgrad, &mut grad);
        (loss, grad)
    }

    fn check_parameter_gradient(tangents: bool) {
        let net = small_net(10.0, 5);
        let pts = points(7, 6);
        let (_, grad) = test_loss(&net, &pts, tangents);
        let h = 2e-3f32;
        let mut worst = 0.0f64;
        for (i, &gi) in grad.iter().enumerate() {
            let mut a = net.clone();
            a.params_mut()[i] += h;
            let mut b = net.clone();
            b.params_mut()[i] -= h;
            let fd = (test_loss(&a, &pts, tangents).0 - test_loss(&b, &pts, tangents).0)
                / (2.0 * h as f64);
            let rel = (fd - gi as f64).abs() / (1.0 + fd.abs());
            worst = worst.max(rel);
        }
        assert!(
            worst < 5e-3,
            "worst relative mismatch of ∂L/∂θ: {worst} (tangents: {tangents})"
        );
    }

    #[test]
    fn parameter_gradient_of_value_loss_matches_finite_differences() {
        check_parameter_gradient(false);
    }

    #[test]
    fn parameter_gradient_of_gradient_loss_matches_finite_differences() {
        check_parameter_gradient(true);
    }

    #[test]
    fn blocks_and_threads_do_not_change_values() {
        let net = small_net(100.0, 8);
        let pts = points(3 * BLOCK + 17, 9);
        let (v, g) = net.eval(&pts, true);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let (v1, g1) = pool.install(|| net.eval(&pts, true));
        assert_eq!(v, v1);
        assert_eq!(g, g1);
        let mut ws = net.workspace();
        net.forward_block(&pts[BLOCK..BLOCK + 5], false, &mut ws);
        for j in 0..5 {
            assert_eq!(ws.value(j), v[BLOCK + j]);
        }
    }
}
