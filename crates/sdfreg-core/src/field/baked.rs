//! Φ baked into a grid: the multi-start's field against a stored model or a mesh, and in a full
//! call against an object (a coarser grid, [`crate::MultistartSettings::grid_cells`]).
//!
//! The multi-start refines 168 starts by a few LM steps each, and against a stored model (Φ
//! frozen) that is half the time of a registration, nearly all of it evaluating the MLP (against
//! a mesh's exact distance, most of it). Φ is fixed there, so it is sampled once — value and gradient at the nodes of a regular grid over
//! the unit frame — and the starts read it by trilinear interpolation of both (≈ 30 times
//! cheaper than the MLP). Points outside the grid are evaluated by the MLP itself, so the
//! field is defined everywhere. Only the first round of the multi-start uses it: its finalists,
//! the alternations, the final LM and every query read the MLP (the grid's few-thousandths
//! error only moves where a start's five coarse steps end).
//!
//! [`BakedGrid::bake`] makes the grid; [`Baked`] is the [`Field`] that reads it. The pipeline's
//! `WithGrid` (crate-private) is a target with its grid as the registration stages see it
//! ([`crate::SdfModel::register`], [`crate::MeshModel::register`]).

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;

use crate::field::Field;

/// Cells along each side of the grid of a stored model ([`crate::SdfModel`]). 48 cells over
/// [`BAKED_HALF_EXTENT`] × 2 = 1.5 unit lengths: a cell of 0.031 (the target's largest side
/// is 1), 49³ nodes, 1.9 MB, baked in about 30 ms on two cores (AVX-512), once per model.
pub const BAKED_CELLS: usize = 48;

/// Half the side of the grid, unit frame: it spans `[-h, h]³` around the target's
/// bounding-box centre, the target (within `[-0.5, 0.5]³`) and a margin of a quarter of its
/// size on each side, where the starts' source points land.
pub const BAKED_HALF_EXTENT: f32 = 0.75;

/// The grid in `cell`, baked from `field` ([`BAKED_CELLS`], [`BAKED_HALF_EXTENT`]) when the cell
/// is empty: a stored model's, made on its first read and kept for the next registrations. The
/// bake runs rayon tasks: see [`crate::base::pool::get_or_make`] (the same field bakes the same
/// bits wherever it runs).
pub(crate) fn baked_once<'c, F: Field + ?Sized>(
    cell: &'c OnceLock<Arc<BakedGrid>>,
    field: &F,
) -> &'c BakedGrid {
    crate::base::pool::get_or_make::<Arc<BakedGrid>>(cell, || {
        Arc::new(BakedGrid::bake(field, BAKED_CELLS, BAKED_HALF_EXTENT))
    })
}

/// Φ and ∇Φ sampled at the nodes of a regular grid (unit frame).
#[derive(Clone)]
pub struct BakedGrid {
    /// The corner node (lowest coordinates).
    origin: f32,
    /// Node spacing.
    cell: f32,
    /// Nodes per side (cells + 1).
    nodes: usize,
    /// `[Φ, ∂Φ/∂x, ∂Φ/∂y, ∂Φ/∂z]` per node, x fastest.
    data: Vec<[f32; 4]>,
}

impl std::fmt::Debug for BakedGrid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BakedGrid")
            .field("origin", &self.origin)
            .field("cell", &self.cell)
            .field("nodes", &self.nodes)
            .finish_non_exhaustive()
    }
}

impl BakedGrid {
    /// Samples `field` on `cells`³ cells spanning `[-half_extent, half_extent]³` (unit frame),
    /// in parallel; the same field gives the same grid, whatever the threads.
    pub fn bake<F: Field + ?Sized>(field: &F, cells: usize, half_extent: f32) -> Self {
        let nodes = cells + 1;
        let origin = -half_extent;
        let cell = 2.0 * half_extent / cells as f32;
        let points: Vec<[f32; 3]> = (0..nodes * nodes * nodes)
            .map(|i| {
                let (x, y, z) = (i % nodes, i / nodes % nodes, i / (nodes * nodes));
                [x, y, z].map(|c| origin + c as f32 * cell)
            })
            .collect();
        let (values, gradients) = field.eval_points(&points, true);
        let data = values
            .par_iter()
            .zip(&gradients)
            .map(|(&v, g)| [v, g[0], g[1], g[2]])
            .collect();
        Self {
            origin,
            cell,
            nodes,
            data,
        }
    }

    /// Whether `other` holds the same nodes, to the bit.
    #[cfg(test)]
    pub(crate) fn same_bits(&self, other: &BakedGrid) -> bool {
        let bits = |g: &BakedGrid| -> Vec<u32> {
            [g.origin, g.cell]
                .into_iter()
                .chain(g.data.iter().flatten().copied())
                .map(f32::to_bits)
                .collect()
        };
        self.nodes == other.nodes && bits(self) == bits(other)
    }

    /// Φ and ∇Φ at `x` by trilinear interpolation of the nodes' values and gradients; `None`
    /// outside the grid.
    pub fn interpolate(&self, x: &[f32; 3]) -> Option<(f32, [f32; 3])> {
        let last = (self.nodes - 1) as f32;
        let mut base = [0usize; 3];
        let mut frac = [0f32; 3];
        for k in 0..3 {
            let u = (x[k] - self.origin) / self.cell;
            // Also refuses NaN.
            if !(0.0..=last).contains(&u) {
                return None;
            }
            let i = (u.floor() as usize).min(self.nodes - 2);
            base[k] = i;
            frac[k] = u - i as f32;
        }
        let n = self.nodes;
        let mut out = [0f32; 4];
        for corner in 0..8 {
            let d = [corner & 1, corner >> 1 & 1, corner >> 2 & 1];
            let w: f32 = (0..3)
                .map(|k| if d[k] == 1 { frac[k] } else { 1.0 - frac[k] })
                .product();
            let node = &self.data[(base[0] + d[0]) + n * ((base[1] + d[1]) + n * (base[2] + d[2]))];
            for (o, v) in out.iter_mut().zip(node) {
                *o += w * v;
            }
        }
        Some((out[0], [out[1], out[2], out[3]]))
    }
}

/// Φ sampled in advance: Φ and ∇Φ at a point where the samples cover it, `None` elsewhere.
pub trait Interpolate: Sync {
    /// Φ and ∇Φ at `x` (unit frame), or `None` where the samples do not cover it.
    fn interpolate(&self, x: &[f32; 3]) -> Option<(f32, [f32; 3])>;
}

impl Interpolate for &BakedGrid {
    fn interpolate(&self, x: &[f32; 3]) -> Option<(f32, [f32; 3])> {
        BakedGrid::interpolate(self, x)
    }
}

impl Interpolate for crate::field::local_grid::SparseBaked<'_> {
    fn interpolate(&self, x: &[f32; 3]) -> Option<(f32, [f32; 3])> {
        crate::field::local_grid::SparseBaked::interpolate(self, x)
    }
}

/// The [`Field`] of a baked `grid` (a [`BakedGrid`], or a local model's corners,
/// [`crate::field::local_grid::SparseBaked`]): interpolated where it covers, `exact` elsewhere.
pub struct Baked<'a, F: Field + ?Sized, G = &'a BakedGrid> {
    /// The grid.
    pub grid: G,
    /// The field it was baked from.
    pub exact: &'a F,
}

impl<F: Field + ?Sized, G: Copy> Clone for Baked<'_, F, G> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<F: Field + ?Sized, G: Copy> Copy for Baked<'_, F, G> {}

impl<F: Field + ?Sized, G: Interpolate> Field for Baked<'_, F, G> {
    fn eval_block(
        &self,
        xs: &[[f32; 3]],
        values: &mut Vec<f32>,
        mut gradients: Option<&mut Vec<[f32; 3]>>,
    ) {
        values.clear();
        if let Some(g) = gradients.as_deref_mut() {
            g.clear();
        }
        let mut outside = Vec::new();
        for (i, x) in xs.iter().enumerate() {
            let (v, g) = self.grid.interpolate(x).unwrap_or_else(|| {
                outside.push(i);
                (0.0, [0.0; 3])
            });
            values.push(v);
            if let Some(gs) = gradients.as_deref_mut() {
                gs.push(g);
            }
        }
        if outside.is_empty() {
            return;
        }
        let far: Vec<[f32; 3]> = outside.iter().map(|&i| xs[i]).collect();
        let (mut v, mut g) = (Vec::new(), Vec::new());
        let want = gradients.is_some();
        self.exact.eval_block(&far, &mut v, want.then_some(&mut g));
        for (j, &i) in outside.iter().enumerate() {
            values[i] = v[j];
            if let Some(gs) = gradients.as_deref_mut() {
                gs[i] = g[j];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Φ of a sphere of radius 0.3 about the origin, exact.
    struct Sphere;
    impl Field for Sphere {
        fn eval_block(
            &self,
            xs: &[[f32; 3]],
            values: &mut Vec<f32>,
            gradients: Option<&mut Vec<[f32; 3]>>,
        ) {
            let norm = |x: &[f32; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
            values.clear();
            values.extend(xs.iter().map(|x| norm(x) - 0.3));
            if let Some(g) = gradients {
                g.clear();
                g.extend(xs.iter().map(|x| x.map(|c| c / norm(x))));
            }
        }
    }

    /// The sphere, whose first evaluation asks for the grid in `cell` (as a registration taken
    /// up by a worker waiting on the bake would).
    struct AsksAgain<'c> {
        cell: &'c OnceLock<Arc<BakedGrid>>,
        asked: std::sync::atomic::AtomicBool,
    }
    impl Field for AsksAgain<'_> {
        fn eval_block(
            &self,
            xs: &[[f32; 3]],
            values: &mut Vec<f32>,
            gradients: Option<&mut Vec<[f32; 3]>>,
        ) {
            if !self.asked.swap(true, std::sync::atomic::Ordering::SeqCst) {
                baked_once(self.cell, &Sphere);
            }
            Sphere.eval_block(xs, values, gradients)
        }
    }

    #[test]
    fn a_grid_asked_for_while_it_is_baked_is_baked_again_not_waited_for() {
        let (send, receive) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let cell = OnceLock::new();
            let field = AsksAgain {
                cell: &cell,
                asked: false.into(),
            };
            let first = baked_once(&cell, &field) as *const BakedGrid;
            let _ = send.send((
                first == Arc::as_ptr(cell.get().unwrap()),
                cell.get().cloned(),
            ));
        });
        // `OnceLock::get_or_init` waits here forever (the inner ask is on the baking thread).
        let (kept, grid) = receive
            .recv_timeout(std::time::Duration::from_secs(60))
            .expect("the grid asked for while it was baked did not return");
        // The inner grid was stored first; the outer call returns it, not its own copy.
        assert!(kept);
        assert!(grid
            .unwrap()
            .same_bits(&BakedGrid::bake(&Sphere, BAKED_CELLS, BAKED_HALF_EXTENT)));
    }

    #[test]
    fn interpolation_is_exact_at_the_nodes_and_close_between_them() {
        let grid = BakedGrid::bake(&Sphere, 48, 0.75);
        let baked = Baked {
            grid: &grid,
            exact: &Sphere,
        };
        // A node: (−0.75 + 20 × 0.03125, …).
        let node = [-0.125f32, 0.0, 0.25];
        let (v, _) = baked.eval_points(&[node], false);
        let (e, _) = Sphere.eval_points(&[node], false);
        assert!((v[0] - e[0]).abs() < 1e-6, "{} vs {}", v[0], e[0]);
        // Between nodes, within 0.1 of the sphere: trilinear error ≪ a cell (0.031).
        let xs: Vec<[f32; 3]> = (0..500)
            .map(|i| {
                // Directions spread over the sphere, radii 0.2–0.4.
                let z = 1.0 - 2.0 * (i as f32 + 0.5) / 500.0;
                let a = i as f32 * 2.399_963;
                let s = (1.0 - z * z).sqrt();
                let r = 0.2 + 0.2 * ((i as f32 * 0.31).sin() * 0.5 + 0.5);
                [r * s * a.cos(), r * s * a.sin(), r * z]
            })
            .collect();
        let (v, g) = baked.eval_points(&xs, true);
        let (e, eg) = Sphere.eval_points(&xs, true);
        let worst_v = v
            .iter()
            .zip(&e)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        let worst_g = g
            .iter()
            .zip(&eg)
            .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>().sqrt())
            .fold(0.0, f32::max);
        assert!(worst_v < 2e-3, "value off by {worst_v}");
        assert!(worst_g < 0.1, "gradient off by {worst_g}");
    }

    #[test]
    fn points_outside_the_grid_read_the_exact_field() {
        let grid = BakedGrid::bake(&Sphere, 8, 0.75);
        let baked = Baked {
            grid: &grid,
            exact: &Sphere,
        };
        let xs = [
            [0.9f32, 0.0, 0.0],
            [0.1, 0.1, 0.1],
            [0.0, -3.0, 0.2],
            [f32::NAN, 0.0, 0.0],
        ];
        let (v, g) = baked.eval_points(&xs, true);
        let (e, eg) = Sphere.eval_points(&xs, true);
        for i in [0, 2] {
            assert_eq!(v[i], e[i]);
            assert_eq!(g[i], eg[i]);
        }
        // Inside a coarse grid the value is interpolated, not exact.
        assert_ne!(v[1], e[1]);
        assert!(v[3].is_nan());
    }
}
